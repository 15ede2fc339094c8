// The H5MD file's time-independent data (species and its element table, mass, charge, id, the
// bonds: engine/io/h5md_writer.hpp) written from the ranks' parts of a decomposed run, the same
// datasets as a setup given per particle (H5mdSetup::species, mass, charge, bonds) writes from
// the whole scene, with no rank holding O(N) of them: rank 0 writes them by rows as it receives
// them in blocks of consecutive global indices and bond places (engine/io/rows_to_root.hpp).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/io/h5md_writer.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// What a setup by rows (H5mdSetup::by_rows) says of the datasets, from the ranks' parts:
// `elements`, the element symbols of the particles' types in order of first appearance by global
// index (what element_table makes of the per-particle species); `charged`, some particle's
// charge is not 0 (Scene::charged); `num_bonds`. Only the types of `description` are read.
// Collective.
void describe_h5md_static(const Scene& description, const PartMolecules& mine, const Communicator& ranks,
                          H5mdSetup& setup);

// Rank 0's `writer` (created by rows from `setup`, which describe_h5md_static filled; null on
// the other ranks) gets every particle's species, mass and charge, and every bond. Collective;
// a writer's failure throws on every rank alike (AgreedInputError; InputError on one rank).
void write_h5md_static_parts(H5mdWriter* writer, const H5mdSetup& setup, const Scene& description,
                             const PartMolecules& mine, const Communicator& ranks);

}  // namespace stiffmd
