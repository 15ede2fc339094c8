"""An H5MD 1.1 layout checker written from the specification (https://nongnu.org/h5md/h5md.html,
version 1.1.0), not from stiffmd's writer; used by tests/test_h5md.py and tests/test_h5md_engine.py.

    problems = h5md_problems(h5py_file)   # [] when the file follows the specification

It checks what the specification mandates: the h5md group (version Integer[2], author/name and
creator/name, creator/version as fixed-length string attributes of scalar dataspace), each particles
subgroup's box (dimension Integer[], boundary fixed-length String[D] of "periodic"/"none", edges
unless every boundary is "none", as a D-vector or D x D matrix, its step/time hard links to
position's), time-dependent elements (step Integer, time Float/Integer, both [variable] and
increasing, value's first dimension equal to theirs; or the fixed step/time storage), image only with
position and on position's step/time, the shapes of position/velocity/force/image [F][N][D],
species Enumeration/Integer, mass Float, id Integer (unique), charge Integer/Float with a
fixed-length `type` attribute, the connectivity tuples (Integer, particles_group an object reference
to a group in /particles, indices valid), observables as elements, and module versions.
"""
import h5py
import numpy as np

STANDARD_VECTORS = ("position", "image", "velocity", "force")


def fixed_string_attribute(obj, name, shape):
    """None if obj.attrs[name] is a fixed-length string of the given dataspace shape, else why not."""
    if name not in obj.attrs:
        return f"{obj.name}: no attribute {name}"
    attr = obj.attrs.get_id(name)
    t = attr.get_type()
    if not isinstance(t, h5py.h5t.TypeStringID):
        return f"{obj.name}@{name}: not a string"
    if t.is_variable_str():
        return f"{obj.name}@{name}: a variable-length string; H5MD asks for fixed-length"
    if attr.shape != shape:
        return f"{obj.name}@{name}: dataspace {attr.shape}, expected {shape or 'scalar'}"
    return None


def strings(values):
    return [v.decode() if isinstance(v, bytes) else str(v) for v in np.atleast_1d(values)]


def is_integer(dtype):
    return dtype.kind in "iu"


def is_enum_or_integer(dataset):
    return is_integer(dataset.dtype) or h5py.check_enum_dtype(dataset.dtype) is not None


def check_time_dependent(group, problems):
    """A time-dependent element: returns the number of samples (or None when malformed)."""
    if "value" not in group or "step" not in group:
        problems.append(f"{group.name}: a time-dependent element needs step and value")
        return None
    value, step = group["value"], group["step"]
    if not is_integer(step.dtype):
        problems.append(f"{step.name}: step must be Integer, is {step.dtype}")
    if step.shape == ():  # fixed step and time storage
        if "time" in group and group["time"].shape != ():
            problems.append(f"{group.name}: fixed step storage needs a scalar time too")
        return value.shape[0]
    n = value.shape[0]
    if step.shape != (n,):
        problems.append(f"{step.name}: shape {step.shape}, expected ({n},) like value's first dimension")
    elif n > 1 and not np.all(np.diff(step[()]) > 0):
        problems.append(f"{step.name}: not monotonically increasing")
    if "time" in group:
        time = group["time"]
        if time.dtype.kind not in "fiu":
            problems.append(f"{time.name}: time must be Float or Integer, is {time.dtype}")
        if time.shape != (n,):
            problems.append(f"{time.name}: shape {time.shape}, expected ({n},)")
        elif n > 1 and not np.all(np.diff(time[()]) > 0):
            problems.append(f"{time.name}: not monotonically increasing")
    if value.maxshape[0] is not None and value.chunks is None:
        problems.append(f"{value.name}: an extensible value must be chunked")
    return n


def element_data(obj):
    """(dataset holding the data, time-dependent?) of an H5MD element."""
    return (obj["value"], True) if isinstance(obj, h5py.Group) else (obj, False)


def same_object(a, b):
    return a.id == b.id  # h5py compares file number and object address: true for hard links


def check_particles_group(group, problems):
    if "box" not in group:
        problems.append(f"{group.name}: every particles subgroup needs a box group")
        return
    box = group["box"]
    dim = box.attrs.get("dimension")
    if dim is None or np.shape(dim) != () or not is_integer(np.asarray(dim).dtype):
        problems.append(f"{box.name}@dimension: must be an Integer scalar, is {dim!r}")
        return
    dim = int(dim)
    why = fixed_string_attribute(box, "boundary", (dim,))
    if why:
        problems.append(why)
    boundary = strings(box.attrs["boundary"]) if "boundary" in box.attrs else []
    if any(b not in ("periodic", "none") for b in boundary):
        problems.append(f"{box.name}@boundary: values must be periodic or none, are {boundary}")
    if "edges" not in box:
        if any(b == "periodic" for b in boundary):
            problems.append(f"{box.name}: edges may be omitted only when every boundary is none")
    else:
        data, timed = element_data(box["edges"])
        item = data.shape[1:] if timed else data.shape
        if item not in ((dim,), (dim, dim)):
            problems.append(f"{data.name}: a box is a {dim}-vector or a {dim} x {dim} matrix, not {item}")
        if timed:
            check_time_dependent(box["edges"], problems)
            if "position" in group and isinstance(group["position"], h5py.Group):
                for d in ("step", "time"):
                    if d in group["position"] and not same_object(box["edges"][d], group["position"][d]):
                        problems.append(f"{box.name}/edges/{d}: must be a hard link to position/{d}")

    n_particles = None
    for name in group:
        if name == "box":
            continue
        obj = group[name]
        data, timed = element_data(obj)
        if timed:
            check_time_dependent(obj, problems)
        shape = data.shape[1:] if timed else data.shape
        if name in STANDARD_VECTORS:
            if len(shape) != 2 or shape[1] != dim:
                problems.append(f"{data.name}: expected [N][{dim}] per sample, is {shape}")
            if data.dtype.kind not in "fiu":
                problems.append(f"{data.name}: must be Float or Integer")
        elif name in ("mass", "species", "id", "charge"):
            if len(shape) != 1:
                problems.append(f"{data.name}: expected [N] per sample, is {shape}")
        else:
            continue
        if shape:
            if n_particles is None:
                n_particles = shape[0]
            elif shape[0] != n_particles:
                problems.append(f"{data.name}: {shape[0]} particles, other elements have {n_particles}")
        if name == "mass" and data.dtype.kind != "f":
            problems.append(f"{data.name}: mass must be Float")
        if name == "species" and not is_enum_or_integer(data):
            problems.append(f"{data.name}: species must be Enumeration or Integer")
        if name == "id":
            if not is_integer(data.dtype):
                problems.append(f"{data.name}: id must be Integer")
            elif not timed and len(np.unique(data[()])) != data.shape[0]:
                problems.append(f"{data.name}: ids must be unique")
        if name == "charge":
            if data.dtype.kind not in "fiu":
                problems.append(f"{data.name}: charge must be Integer or Float")
            if "type" in obj.attrs:
                why = fixed_string_attribute(obj, "type", ())
                if why:
                    problems.append(why)
    if "image" in group:
        if "position" not in group:
            problems.append(f"{group.name}/image: image needs position")
        elif isinstance(group["image"], h5py.Group) and isinstance(group["position"], h5py.Group):
            for d in ("step", "time"):
                if d in group["image"] and not same_object(group["image"][d], group["position"][d]):
                    problems.append(f"{group.name}/image/{d}: must be a hard link to position/{d}")
    return n_particles


def check_observables(group, problems):
    for name in group:
        obj = group[name]
        if isinstance(obj, h5py.Group):
            if "value" in obj:
                check_time_dependent(obj, problems)
            else:
                check_observables(obj, problems)  # a subgroup of observables


def check_connectivity(f, group, sizes, problems):
    for name in group:
        obj = group[name]
        data, timed = element_data(obj)
        if not is_integer(data.dtype):
            problems.append(f"{data.name}: connectivity tuples must be Integer")
            continue
        ref = obj.attrs.get("particles_group")
        if not isinstance(ref, h5py.Reference) or not ref:
            problems.append(f"{obj.name}@particles_group: must be an object reference")
            continue
        target = f[ref]
        if not isinstance(target, h5py.Group) or target.parent.name != "/particles":
            problems.append(f"{obj.name}@particles_group: must refer to a group in /particles, refers to {target.name}")
            continue
        values = data[()]
        if "id" in target:
            ids = set(element_data(target["id"])[0][()].ravel().tolist())
            bad = [v for v in values.ravel().tolist() if v not in ids]
        else:
            n = sizes.get(target.name)
            bad = [v for v in values.ravel().tolist() if n is not None and not 0 <= v < n]
        if bad:
            problems.append(f"{data.name}: {len(bad)} indices name no particle of {target.name}")


def h5md_problems(f):
    """Every departure of the open h5py File f from H5MD 1.1 found, as one line each."""
    problems = []
    if "h5md" not in f:
        return ["no /h5md group (the one mandatory group)"]
    h5md = f["h5md"]
    version = h5md.attrs.get("version")
    if version is None or np.shape(version) != (2,) or not is_integer(np.asarray(version).dtype):
        problems.append(f"/h5md@version: must be Integer[2], is {version!r}")
    elif int(version[0]) != 1:
        problems.append(f"/h5md@version: {list(version)}, this checker knows 1.x")
    for group, names in (("author", ("name",)), ("creator", ("name", "version"))):
        if group not in h5md:
            problems.append(f"/h5md/{group}: missing")
            continue
        for name in names:
            why = fixed_string_attribute(h5md[group], name, ())
            if why:
                problems.append(why)
        if group == "author" and "email" in h5md[group].attrs:
            why = fixed_string_attribute(h5md[group], "email", ())
            if why:
                problems.append(why)
    if "modules" in h5md:
        for name in h5md["modules"]:
            v = h5md["modules"][name].attrs.get("version")
            if v is None or np.shape(v) != (2,):
                problems.append(f"/h5md/modules/{name}@version: must be Integer[2]")
    sizes = {}
    if "particles" in f:
        for name in f["particles"]:
            sizes[f["particles"][name].name] = check_particles_group(f["particles"][name], problems)
    if "observables" in f:
        check_observables(f["observables"], problems)
    if "connectivity" in f:
        check_connectivity(f, f["connectivity"], sizes, problems)
    return problems
