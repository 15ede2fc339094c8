// Test driver for engine/h5md_writer.* (run by tests/test_h5md.py until the engine's run loop
// writes H5MD itself). Each scene writes PREFIX.h5 with H5mdWriter and, next to it, what was
// written in plain text: PREFIX.xyz (extended XYZ, unwrapped positions, %.17g) and PREFIX.csv
// (step, time, observables) — the same pair of files `stiffmd run` writes, so the test compares
// the H5MD file against them either way.
//
//   h5md_driver open PREFIX             open box, 3 particles, 2 bonds, forces
//   h5md_driver periodic PREFIX         periodic box, 20 particles crossing its faces, velocities, gzip
//   h5md_driver slab PREFIX             periodic in x and y only
//   h5md_driver append PREFIX           5 frames, reopen with first_step = 30, 5 more frames
//   h5md_driver forever PREFIX [MS [GZIP]]  a frame every MS (20) ms until killed, gzip level GZIP (1);
//                                       "frame K" on stdout after each
//   h5md_driver resume PREFIX STEP      reopen a `forever` file (append, first_step STEP), 2 more frames
//   h5md_driver errors DIR              the error cases, one "case<TAB>message" line each
//
// Build: g++ -std=c++20 -O2 -Wall -Wextra -I. -I/usr/include/eigen3 -I/usr/include/hdf5/serial
//        engine/io/h5md_writer.cpp tests/h5md_driver.cpp -L/usr/lib/x86_64-linux-gnu/hdf5/serial -lhdf5
#include <hdf5.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include "core/errors.hpp"
#include "engine/io/h5md_writer.hpp"

namespace {

using stiffmd::H5mdSetup;
using stiffmd::H5mdWriter;

struct Frame {
  std::int64_t step;
  double time;
  Eigen::Matrix3Xd x, v, f;
  std::vector<double> obs;
};

// The plain-text record of what went into the H5MD file.
class Reference {
 public:
  Reference(const std::string& prefix, const H5mdSetup& s, bool append)
      : xyz_(prefix + ".xyz", append ? std::ios::app : std::ios::trunc),
        csv_(prefix + ".csv", append ? std::ios::app : std::ios::trunc),
        setup_(s) {
    xyz_.precision(17);
    csv_.precision(17);
    if (!append) {
      csv_ << "step,time";
      for (const auto& o : s.observables) csv_ << ',' << o;
      csv_ << '\n';
    }
  }
  void write(const Frame& fr) {
    const auto& b = setup_.box;
    xyz_ << setup_.num_particles << "\nProperties=species:S:1:pos:R:3" << (setup_.velocity ? ":velo:R:3" : "")
         << (setup_.force ? ":forces:R:3" : "") << " time=" << fr.time << " step=" << fr.step << " pbc=\""
         << (b.periodic[0] ? 'T' : 'F') << ' ' << (b.periodic[1] ? 'T' : 'F') << ' ' << (b.periodic[2] ? 'T' : 'F')
         << '"';
    if (b.any_periodic())
      xyz_ << " Lattice=\"" << b.lengths[0] << " 0 0 0 " << b.lengths[1] << " 0 0 0 " << b.lengths[2] << "\" Origin=\""
           << b.origin[0] << ' ' << b.origin[1] << ' ' << b.origin[2] << '"';
    xyz_ << '\n';
    for (int i = 0; i < setup_.num_particles; ++i) {
      xyz_ << setup_.species[i];
      for (int k = 0; k < 3; ++k) xyz_ << ' ' << fr.x(k, i);
      if (setup_.velocity)
        for (int k = 0; k < 3; ++k) xyz_ << ' ' << fr.v(k, i);
      if (setup_.force)
        for (int k = 0; k < 3; ++k) xyz_ << ' ' << fr.f(k, i);
      xyz_ << '\n';
    }
    csv_ << fr.step << ',' << fr.time;
    for (double o : fr.obs) csv_ << ',' << o;
    csv_ << '\n';
    xyz_.flush();
    csv_.flush();
  }

 private:
  std::ofstream xyz_, csv_;
  H5mdSetup setup_;
};

H5mdSetup base_setup(int n, const std::vector<std::string>& elements) {
  H5mdSetup s;
  s.num_particles = n;
  s.mass.resize(n);
  for (int i = 0; i < n; ++i) {
    s.species.push_back(elements[i % elements.size()]);
    s.mass[i] = 1.0 + 0.5 * (i % 3);
  }
  s.author = "h5md driver";
  s.creator_version = "0.0-test";
  s.observables = {"kinetic", "potential_slow", "potential_stiff", "total", "max_violation", "action_1"};
  return s;
}

// Smooth motion with drift: particle i moves with velocity c_i, so periodic scenes cross faces.
Frame make_frame(const H5mdSetup& s, std::int64_t step, double dt, double shift) {
  Frame fr;
  fr.step = step;
  fr.time = step * dt;
  const double t = fr.time;
  const int n = s.num_particles;
  fr.x.resize(3, n);
  fr.v.resize(3, n);
  fr.f.resize(3, n);
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) {
      const double c = (i % 2 ? -1.0 : 1.0) * (0.7 + 0.37 * i + 0.11 * k);  // drift speed
      const double w = 1.0 + 0.1 * i, a = 0.05 * (k + 1);
      fr.x(k, i) = shift + 0.3 * i + 0.2 * k + c * t + a * std::sin(w * t);
      fr.v(k, i) = c + a * w * std::cos(w * t);
      fr.f(k, i) = -s.mass[i] * a * w * w * std::sin(w * t);
    }
  double ke = 0;
  for (int i = 0; i < n; ++i) ke += 0.5 * s.mass[i] * fr.v.col(i).squaredNorm();
  fr.obs = {ke,          -1.0 - 0.01 * t, 1e-3 * std::cos(t), ke - 1.0 - 0.01 * t + 1e-3 * std::cos(t),
            1e-9 * step, 0.25 + 1e-6 * t};
  return fr;
}

void run_scene(const std::string& prefix, const H5mdSetup& s, int frames, std::int64_t step_stride, double dt) {
  H5mdWriter w(prefix + ".h5", s);
  Reference ref(prefix, s, false);
  for (int k = 0; k < frames; ++k) {
    const Frame fr = make_frame(s, k * step_stride, dt, 0.0);
    w.write_frame(fr.step, fr.time, fr.x, s.velocity ? &fr.v : nullptr, s.force ? &fr.f : nullptr, fr.obs);
    ref.write(fr);
  }
  if (w.frames() != frames) throw std::runtime_error("frames() does not count the frames written");
}

H5mdSetup open_scene() {
  H5mdSetup s = base_setup(3, {"C", "O", "C"});
  s.bonds = {{0, 1}, {1, 2}};
  s.force = true;
  s.author = "";  // falls back to $USER
  return s;
}

H5mdSetup periodic_scene() {
  H5mdSetup s = base_setup(20, {"Fe", "C", "H", "N"});
  s.box.origin = Eigen::Vector3d(-1.0, 0.0, 0.5);
  s.box.lengths = Eigen::Vector3d(3.0, 4.0, 5.0);
  s.box.periodic = Eigen::Vector3i(1, 1, 1);
  s.bonds = {{0, 1}, {2, 3}, {4, 5}};
  s.velocity = true;
  s.gzip = 4;
  return s;
}

H5mdSetup slab_scene() {
  H5mdSetup s = base_setup(5, {"Ar"});
  s.box.lengths = Eigen::Vector3d(2.0, 2.5, 0.0);  // the open axis has no length
  s.box.periodic = Eigen::Vector3i(1, 1, 0);
  s.velocity = true;
  s.force = true;
  return s;
}

// 5 frames (steps 0..40), then a "restart" from step 30: frames 30 and 40 are dropped and the
// continuation (shifted by 100, so the test can tell old from new) writes steps 30..70.
void append_scene(const std::string& prefix) {
  H5mdSetup s = periodic_scene();
  const std::string path = prefix + ".h5";
  {
    H5mdWriter w(path, s);
    for (int k = 0; k < 5; ++k) {
      const Frame fr = make_frame(s, 10 * k, 0.01, 0.0);
      w.write_frame(fr.step, fr.time, fr.x, &fr.v, nullptr, fr.obs);
    }
  }
  {
    Reference ref(prefix, s, false);
    for (int k = 0; k < 3; ++k) ref.write(make_frame(s, 10 * k, 0.01, 0.0));
  }
  H5mdWriter w(path, s, true, 30);
  if (w.frames() != 3) throw std::runtime_error("append kept " + std::to_string(w.frames()) + " frames, not 3");
  Reference ref(prefix, s, true);
  for (int k = 3; k < 8; ++k) {
    const Frame fr = make_frame(s, 10 * k, 0.01, 100.0);
    w.write_frame(fr.step, fr.time, fr.x, &fr.v, nullptr, fr.obs);
    ref.write(fr);
  }
}

H5mdSetup forever_scene() {
  H5mdSetup s = periodic_scene();
  s.force = true;
  s.gzip = 1;
  return s;
}

[[noreturn]] void forever(const std::string& prefix, int sleep_ms, int gzip) {
  H5mdSetup s = forever_scene();
  s.gzip = gzip;
  H5mdWriter w(prefix + ".h5", s);
  Reference ref(prefix, s, false);
  for (std::int64_t k = 0;; ++k) {
    const Frame fr = make_frame(s, 5 * k, 0.002, 0.0);
    w.write_frame(fr.step, fr.time, fr.x, &fr.v, &fr.f, fr.obs);
    ref.write(fr);
    std::printf("frame %lld\n", static_cast<long long>(k));
    std::fflush(stdout);
    std::this_thread::sleep_for(std::chrono::milliseconds(sleep_ms));
  }
}

// Continue a killed `forever` run as a restart would: frames from first_step on are replaced.
void resume(const std::string& prefix, std::int64_t first_step) {
  const H5mdSetup s = forever_scene();
  H5mdWriter w(prefix + ".h5", s, true, first_step);
  std::printf("kept %lld\n", static_cast<long long>(w.frames()));
  for (std::int64_t k = first_step / 5; k < first_step / 5 + 2; ++k) {
    const Frame fr = make_frame(s, 5 * k, 0.002, 0.0);
    w.write_frame(fr.step, fr.time, fr.x, &fr.v, &fr.f, fr.obs);
  }
  std::printf("frames %lld\n", static_cast<long long>(w.frames()));
}

// Each case must throw InputError; prints "case<TAB>message".
void errors(const std::string& dir) {
  auto expect_error = [](const std::string& name, auto&& make) {
    try {
      make();
      std::printf("%s\tNO ERROR\n", name.c_str());
    } catch (const stiffmd::InputError& e) {
      std::printf("%s\t%s\n", name.c_str(), e.what());
    }
  };
  const H5mdSetup s = open_scene();
  expect_error("missing_directory", [&] { H5mdWriter(dir + "/no/such/dir/traj.h5", s); });
  expect_error("path_is_directory", [&] { H5mdWriter(dir, s); });
  const std::string ro = dir + "/readonly";
  mkdir(ro.c_str(), 0500);
  if (geteuid() != 0)  // root ignores permissions
    expect_error("unwritable_directory", [&] { H5mdWriter(ro + "/traj.h5", s); });
  expect_error("append_missing_file", [&] { H5mdWriter(dir + "/absent.h5", s, true, 0); });
  std::ofstream(dir + "/text.h5") << "not hdf5\n";
  expect_error("append_not_hdf5", [&] { H5mdWriter(dir + "/text.h5", s, true, 0); });
  const std::string plain = dir + "/plain.h5";
  H5Fclose(H5Fcreate(plain.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT));
  expect_error("append_not_stiffmd", [&] { H5mdWriter(plain, s, true, 0); });
  const std::string good = dir + "/good.h5";
  H5mdWriter(good, s);
  H5mdSetup more = base_setup(4, {"C"});
  more.force = true;
  expect_error("append_particle_count", [&] { H5mdWriter(good, more, true, 0); });
  H5mdSetup with_v = s;
  with_v.velocity = true;
  expect_error("append_velocity_mismatch", [&] { H5mdWriter(good, with_v, true, 0); });
  H5mdSetup other_obs = s;
  other_obs.observables.pop_back();
  expect_error("append_observables_mismatch", [&] { H5mdWriter(good, other_obs, true, 0); });
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: h5md_driver open|periodic|slab|append|forever|resume|errors PREFIX [STEP]\n");
    return 2;
  }
  const std::string mode = argv[1], prefix = argv[2];
  try {
    if (mode == "open")
      run_scene(prefix, open_scene(), 6, 100, 0.001);
    else if (mode == "periodic")
      run_scene(prefix, periodic_scene(), 8, 50, 0.01);
    else if (mode == "slab")
      run_scene(prefix, slab_scene(), 4, 1, 0.25);
    else if (mode == "append")
      append_scene(prefix);
    else if (mode == "forever")
      forever(prefix, argc > 3 ? std::stoi(argv[3]) : 20, argc > 4 ? std::stoi(argv[4]) : 1);
    else if (mode == "resume" && argc > 3)
      resume(prefix, std::stoll(argv[3]));
    else if (mode == "errors")
      errors(prefix);
    else
      throw std::runtime_error("unknown mode " + mode);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
