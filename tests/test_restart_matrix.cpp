// The restart matrix: every method × a melt with every kind of force term (tests/decks/
// restart_melt.toml: stiff bonds, WCA pairs through a neighbour list, bending, a tether; periodic
// box) × interruptions — SIGTERM and SIGINT at exact steps, SIGKILL with a restart from the
// periodic checkpoint, interruptions of a restarted run — each continued with --restart. The
// outputs must be the uninterrupted run's: thermo.csv, trajectory.xyz and the final checkpoint
// byte for byte, every H5MD dataset value for value, summary.json but for its timings.
//
// Also: damaged, truncated, foreign and newer checkpoints are refused with exit 2 and one line,
// before anything is printed or any output file is touched; the progress bar of a stopped run
// ends where the run stopped.
#include <gtest/gtest.h>
#include <hdf5.h>
#include <zlib.h>

#include <csignal>
#include <cstring>
#include <map>
#include <random>

#include "cli_support.hpp"
#include "engine/run/checkpoint.hpp"
#include "integrators/methods.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using test::cli;
using test::slurp;

std::string melt() {
  return test::source_path("tests/decks/restart_melt.toml");
}

// Every dataset of an HDF5 file by path: its shape and values (fixed-size data as the bytes of
// its native type, variable-length strings as the strings), so that two files of different
// layout compare equal exactly when their contents do.
std::map<std::string, std::string> h5_datasets(const fs::path& file) {
  std::map<std::string, std::string> out;
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0) return out;
  auto visit = [](hid_t obj, const char* name, const H5O_info_t* info, void* data) -> herr_t {
    if (info->type != H5O_TYPE_DATASET) return 0;
    auto& into = *static_cast<std::map<std::string, std::string>*>(data);
    const hid_t d = H5Dopen2(obj, name, H5P_DEFAULT);
    const hid_t space = H5Dget_space(d);
    const int rank = H5Sget_simple_extent_ndims(space);
    std::vector<hsize_t> dims(static_cast<size_t>(std::max(rank, 0)));
    H5Sget_simple_extent_dims(space, dims.data(), nullptr);
    const auto points = static_cast<size_t>(H5Sget_simple_extent_npoints(space));
    std::string value = "dims";
    for (hsize_t n : dims) value += " " + std::to_string(n);
    value += ":";
    const hid_t file_type = H5Dget_type(d);
    if (H5Tget_class(file_type) == H5T_STRING && H5Tis_variable_str(file_type) > 0) {
      std::vector<char*> s(points);
      const hid_t t = H5Tcopy(H5T_C_S1);
      H5Tset_size(t, H5T_VARIABLE);
      H5Dread(d, t, H5S_ALL, H5S_ALL, H5P_DEFAULT, s.data());
      for (char* c : s) value += std::string(c ? c : "") + '\0';
      H5Dvlen_reclaim(t, space, H5P_DEFAULT, s.data());
      H5Tclose(t);
    } else {
      const hid_t t = H5Tget_native_type(file_type, H5T_DIR_ASCEND);
      std::string bytes(points * H5Tget_size(t), '\0');
      H5Dread(d, t, H5S_ALL, H5S_ALL, H5P_DEFAULT, bytes.data());
      value += bytes;
      H5Tclose(t);
    }
    into[name] = value;
    H5Tclose(file_type);
    H5Sclose(space);
    H5Dclose(d);
    return 0;
  };
  H5Ovisit2(f, H5_INDEX_NAME, H5_ITER_NATIVE, visit, &out, H5O_INFO_BASIC);
  H5Fclose(f);
  return out;
}

// summary.json without the lines that measure the machine: time, and the process's peak memory.
std::string summary_without_timings(const fs::path& p) {
  std::istringstream in(slurp(p));
  std::string out;
  for (std::string line; std::getline(in, line);)
    if (line.find("_seconds") == std::string::npos && line.find("\"peak_rss_mib\"") == std::string::npos)
      out += line + "\n";
  return out;
}

struct MethodRun {
  std::string method;
  std::int64_t steps;  // 120 macro steps (velocity Verlet: 1200 at h = ε/20)
  std::string args;
};

MethodRun method_run(const std::string& method) {
  const bool vv = method == "velocity-verlet";
  const std::int64_t steps = vv ? 1200 : 120;
  // A method whose model potential is a free energy at kT (fixman) runs under a Langevin thermostat.
  const std::string thermostat = find_method(method)->needs_temperature
                                     ? " --set thermostat.style=langevin --set thermostat.temperature=1"
                                       " --set thermostat.friction=1 --set thermostat.seed=5"
                                     : "";
  return {method, steps,
          " --no-progress --set integrator.method=" + method + (vv ? " --set integrator.h=0.0005" : "") + thermostat +
              // a checkpoint every third of the run: 40 steps of 0.005, 400 of 0.0005
              " --set output.checkpoint_interval=0.2"};
}

// Runs the melt into dir, with a signal raised at an exact step if sig > 0.
test::CliResult run(const MethodRun& m, const fs::path& dir, std::int64_t signal_step = -1, int sig = 0,
                    const std::string& restart = "") {
  const std::string env =
      sig > 0 ? "STIFFMD_SIGNAL_AT_STEP=" + std::to_string(signal_step) + ":" + std::to_string(sig) + " " : "";
  return cli("run " + melt() + " -o " + dir.string() + m.args + (restart.empty() ? "" : " --restart " + restart), env);
}

void expect_same_outputs(const fs::path& whole, const fs::path& parts, const std::string& what) {
  SCOPED_TRACE(what);
  EXPECT_EQ(slurp(whole / "thermo.csv"), slurp(parts / "thermo.csv")) << "thermo.csv differs";
  EXPECT_TRUE(slurp(whole / "trajectory.xyz") == slurp(parts / "trajectory.xyz")) << "trajectory.xyz differs";
  const auto a = h5_datasets(whole / "trajectory.h5"), b = h5_datasets(parts / "trajectory.h5");
  EXPECT_GT(a.size(), 5u);
  EXPECT_EQ(a.size(), b.size());
  for (const auto& [name, value] : a) {
    const auto it = b.find(name);
    ASSERT_NE(it, b.end()) << "H5MD dataset " << name << " missing";
    if (it->second != value) {
      ADD_FAILURE() << "H5MD dataset " << name << " differs (and maybe others)";
      break;
    }
  }
  EXPECT_TRUE(slurp(whole / "checkpoint.bin") == slurp(parts / "checkpoint.bin")) << "final checkpoint differs";
  EXPECT_EQ(summary_without_timings(whole / "summary.json"), summary_without_timings(parts / "summary.json"));
}

void expect_every_interruption_continues_bit_for_bit(const MethodRun& m, const std::string& name) {
  const std::int64_t n = m.steps, every = n / 3;
  const fs::path d = test::scratch_dir("restart_matrix_" + name);
  auto r = run(m, d / "whole");
  ASSERT_EQ(r.code, 0) << r.err;
  ASSERT_NE(r.err.find("warning: monitor"), std::string::npos) << "the deck should make the monitor warn";

  // SIGTERM between two samples (no thermo row, XYZ or H5MD frame at this step).
  const std::int64_t k1 = 37 * n / 120;
  r = run(m, d / "term", k1, SIGTERM);
  ASSERT_EQ(r.code, 128 + SIGTERM) << r.err;
  EXPECT_NE(r.err.find("stopped by signal 15 after step " + std::to_string(k1)), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(d / "term" / "summary.json"));
  r = run(m, d / "term", -1, 0, (d / "term" / "checkpoint.bin").string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("warning: monitor"), std::string::npos) << "said again after the restart:\n" << r.err;
  expect_same_outputs(d / "whole", d / "term", "SIGTERM at step " + std::to_string(k1));

  // SIGTERM at a step with a thermo row (t = 0.45).
  const std::int64_t k2 = 90 * n / 120;
  ASSERT_EQ(run(m, d / "term2", k2, SIGTERM).code, 128 + SIGTERM);
  ASSERT_EQ(run(m, d / "term2", -1, 0, (d / "term2" / "checkpoint.bin").string()).code, 0);
  expect_same_outputs(d / "whole", d / "term2", "SIGTERM at step " + std::to_string(k2));

  // SIGINT after the first step; the restarted run killed (SIGKILL) after step k3, past its
  // periodic checkpoint at 2n/3; continued from that checkpoint, whose run wrote frames beyond it.
  const std::int64_t k3 = 101 * n / 120;
  ASSERT_EQ(run(m, d / "kill", 1, SIGINT).code, 128 + SIGINT);
  const std::string ck = (d / "kill" / "checkpoint.bin").string();
  ASSERT_EQ(run(m, d / "kill", k3, SIGKILL, ck).code, 128 + SIGKILL);
  EXPECT_EQ(read_checkpoint(ck).state.step, k3 / every * every) << "the periodic checkpoint";
  r = run(m, d / "kill", -1, 0, ck);
  ASSERT_EQ(r.code, 0) << r.err;
  expect_same_outputs(d / "whole", d / "kill", "SIGINT at step 1, SIGKILL at step " + std::to_string(k3));
  fs::remove_all(d);
}

class RestartMatrix : public ::testing::TestWithParam<std::string> {};

TEST_P(RestartMatrix, EveryInterruptionContinuesBitForBit) {
  expect_every_interruption_continues_bit_for_bit(method_run(GetParam()), GetParam());
}

// Langevin as a force (splitting = "lammps"): the friction and noise force of the last step lives
// in the impulse method's cached slow kick force, which the checkpoint must carry.
TEST(RestartMatrix, LangevinForceSplittingContinuesBitForBit) {
  MethodRun m = method_run("impulse");
  m.args +=
      " --set thermostat.style=langevin --set thermostat.temperature=1 --set thermostat.friction=1"
      " --set thermostat.seed=5 --set thermostat.splitting=lammps";
  expect_every_interruption_continues_bit_for_bit(m, "impulse_langevin_force");
}

// OBABO (splitting = "obabo"): the kinetic energy of the closing O step is the thermo's temperature
// and part of the saved state; fixman's path (Rattle, one SHAKE per step) and the impulse method's
// (the O steps around the r-RESPA macro step).
TEST(RestartMatrix, ObaboSplittingContinuesBitForBit) {
  for (const char* method : {"fixman", "impulse"}) {
    SCOPED_TRACE(method);
    MethodRun m = method_run(method);
    if (!find_method(method)->needs_temperature)
      m.args +=
          " --set thermostat.style=langevin --set thermostat.temperature=1 --set thermostat.friction=1"
          " --set thermostat.seed=5";
    m.args += " --set thermostat.splitting=obabo";
    expect_every_interruption_continues_bit_for_bit(m, std::string(method) + "_obabo");
  }
}

INSTANTIATE_TEST_SUITE_P(EveryMethod, RestartMatrix, ::testing::ValuesIn(test::kAllMethods), test::method_test_name);

// The case: SIGTERM from outside (kill) at whatever step the run has reached once its
// step loop is running (thermo.csv has rows), on a run of 1000 steps.
TEST(RestartMatrixExternalSignal, SigtermAtARandomStepContinuesBitForBit) {
  const fs::path d = test::scratch_dir("restart_external_term");
  const std::string args = " --no-progress --set integrator.method=mollified-impulse --set run.t_end=5";
  auto r = cli("run " + melt() + " -o " + (d / "whole").string() + args);
  ASSERT_EQ(r.code, 0) << r.err;
  const fs::path parts = d / "parts", err = d / "parts.err";
  const std::string script =
      std::string(STIFFMD_EXE) + " run " + melt() + " -o " + parts.string() + args + " >/dev/null 2>" + err.string() +
      " & pid=$!; for i in $(seq 1000); do " + "[ $(cat " + (parts / "thermo.csv").string() +
      " 2>/dev/null | wc -l) -ge 5 ] && break; sleep 0.005; done; " + "kill -TERM $pid; wait $pid; exit $?";
  const int status = std::system(("sh -c '" + script + "'").c_str());
  const std::string log = slurp(err);
  if (log.find("stopped by signal 15") == std::string::npos)
    GTEST_SKIP() << "the run ended before the signal (exit status " << status << "): " << log;
  EXPECT_EQ(WEXITSTATUS(status), 128 + SIGTERM) << log;
  r = cli("run " + melt() + " -o " + parts.string() + args + " --restart " + (parts / "checkpoint.bin").string());
  ASSERT_EQ(r.code, 0) << r.err;
  expect_same_outputs(d / "whole", parts, log + r.err);
  fs::remove_all(d);
}

// [monitor] on_alert = "stop" keeps the last sample within the thresholds as a whole checkpoint
// (a snapshot of everything, not the state at the alert with the integrator's state of later):
// continued with on_alert = "warn", the run is the uninterrupted "warn" run.
TEST(RestartMatrixMonitorStop, TheLastGoodStateContinuesBitForBit) {
  const fs::path d = test::scratch_dir("restart_monitor_stop");
  const std::string args = " --no-progress --set integrator.method=rattle --set monitor.energy_error=2e-4";
  auto r = cli("run " + melt() + " -o " + (d / "whole").string() + args);
  ASSERT_EQ(r.code, 0) << r.err;
  ASSERT_NE(r.err.find("warning: monitor: relative energy error"), std::string::npos) << r.err;
  r = cli("run " + melt() + " -o " + (d / "parts").string() + args + " --set monitor.on_alert=\\\"stop\\\"");
  ASSERT_EQ(r.code, 3) << r.err;
  const std::string ck = (d / "parts" / "checkpoint.bin").string();
  const Checkpoint c = read_checkpoint(ck);
  EXPECT_GT(c.state.step, 0);
  EXPECT_NE(r.err.find("(step " + std::to_string(c.state.step) + ","), std::string::npos) << r.err;
  r = cli("run " + melt() + " -o " + (d / "parts").string() + args + " --restart " + ck);
  ASSERT_EQ(r.code, 0) << r.err;
  expect_same_outputs(d / "whole", d / "parts", "restart from the monitor's checkpoint");
  fs::remove_all(d);
}

// A restart with another h continues from the checkpoint's time (t = t_k + (j − k) h'), not
// from k h' (which went back in time when h shrank); a second restart with h' goes on from there.
TEST(RestartWithAnotherStep, ContinuesFromTheCheckpointsTime) {
  const fs::path d = test::scratch_dir("restart_new_h");
  const std::string out = " -o " + d.string() + " --no-progress --set integrator.method=rattle";
  ASSERT_EQ(cli("run " + melt() + out + " --set run.t_end=0.3").code, 0);  // 60 steps of 0.005
  const std::string ck = " --restart " + (d / "checkpoint.bin").string();
  auto r = cli("run " + melt() + out + " --set run.t_end=0.45 --set integrator.h=0.0025" + ck);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("not bit-identical"), std::string::npos) << r.err;
  r = cli("run " + melt() + out + " --set run.t_end=0.6 --set integrator.h=0.0025" + ck);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("not bit-identical"), std::string::npos) << "the same h as the checkpoint's:\n" << r.err;
  EXPECT_NE(r.out.find("steps:         180 to t = 0.6"), std::string::npos) << r.out;  // 60 + 120
  const test::CsvTable t = test::read_csv((d / "thermo.csv").string());
  const size_t time = t.col("time"), step = t.col("step");
  for (size_t k = 1; k < t.rows.size(); ++k) {
    EXPECT_GT(t.rows[k][time], t.rows[k - 1][time]) << "row " << k;
    EXPECT_GT(t.rows[k][step], t.rows[k - 1][step]) << "row " << k;
  }
  EXPECT_NEAR(t.rows.back()[time], 0.6, 1e-12);
  EXPECT_EQ(t.rows.back()[step], 180.0);
  const Checkpoint c = read_checkpoint((d / "checkpoint.bin").string());
  EXPECT_EQ(c.state.step, 180);
  EXPECT_NEAR(c.state.t, 0.6, 1e-12);
  fs::remove_all(d);
}

// ---- checkpoints that must be refused ----

// Every file of a directory with its contents.
std::map<std::string, std::string> directory_contents(const fs::path& d) {
  std::map<std::string, std::string> m;
  for (const auto& e : fs::directory_iterator(d)) m[e.path().filename().string()] = slurp(e.path());
  return m;
}

class BadCheckpoint : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = test::scratch_dir("bad_checkpoint");
    // A finished run to t = 0.05 (10 steps); its checkpoint is the good one the tests damage.
    const auto r = cli("run " + melt() + " -o " + (dir_ / "out").string() + " --no-progress --set run.t_end=0.05");
    ASSERT_EQ(r.code, 0) << r.err;
    good_ = slurp(dir_ / "out" / "checkpoint.bin");
    before_ = directory_contents(dir_ / "out");
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }

  // A restart from `bytes` is refused: exit 2, one line on stderr naming the file and containing
  // `what`, nothing on stdout, the output directory untouched.
  static void expect_refused(const std::string& bytes, const std::string& what, const std::string& extra = "") {
    const fs::path p = dir_ / "bad.bin";
    std::ofstream(p, std::ios::binary) << bytes;
    const auto r = cli("run " + melt() + " -o " + (dir_ / "out").string() + " --no-progress --set run.t_end=0.1" +
                       extra + " --restart " + p.string());
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_EQ(r.err.rfind("error: " + p.string() + ": ", 0), 0u) << r.err;
    bool named = false;  // `what` may list alternatives separated by '|'
    for (size_t b = 0, e; b <= what.size(); b = e + 1) {
      e = std::min(what.find('|', b), what.size());
      named |= r.err.find(what.substr(b, e - b)) != std::string::npos;
    }
    EXPECT_TRUE(named) << "expected " << what << ", got " << r.err;
    EXPECT_EQ(r.out, "");
    EXPECT_TRUE(directory_contents(dir_ / "out") == before_) << "an output file was touched";
  }

  static std::string with_crc(std::string b) {  // recomputes the crc32 of bytes 12 … end
    const auto crc = static_cast<std::uint32_t>(
        ::crc32(0, reinterpret_cast<const Bytef*>(b.data()) + 12, static_cast<uInt>(b.size() - 12)));
    std::memcpy(b.data() + 8, &crc, 4);
    return b;
  }

  static inline fs::path dir_;
  static inline std::string good_;
  static inline std::map<std::string, std::string> before_;
};

TEST_F(BadCheckpoint, TheGoodOneContinues) {
  // The control: the same command with the undamaged checkpoint runs (in a copy of the outputs).
  fs::copy(dir_ / "out", dir_ / "copy");
  const auto r = cli("run " + melt() + " -o " + (dir_ / "copy").string() + " --no-progress --set run.t_end=0.1" +
                     " --restart " + (dir_ / "copy" / "checkpoint.bin").string());
  EXPECT_EQ(r.code, 0) << r.err;
  fs::remove_all(dir_ / "copy");
}

TEST_F(BadCheckpoint, AnyFlippedBitIsCaught) {
  std::mt19937 rng(2024);
  std::uniform_int_distribution<size_t> offset(0, good_.size() - 1);
  std::uniform_int_distribution<int> bit(0, 7);
  std::vector<size_t> offsets = {8, 12, 24, 40, 48, good_.size() - 1};  // crc, version, length, particles, step, end
  for (int k = 0; k < 24; ++k) offsets.push_back(offset(rng));
  for (const size_t at : offsets) {
    SCOPED_TRACE("bit flipped at byte " + std::to_string(at));
    std::string b = good_;
    b[at] = static_cast<char>(b[at] ^ (1 << bit(rng)));
    // A flip in the length field that makes it longer than the file reads as a truncation.
    expect_refused(b, at < 8                ? "not a stiffmd checkpoint"
                      : at >= 24 && at < 32 ? "damaged checkpoint|truncated checkpoint"
                                            : "damaged checkpoint");
  }
}

TEST_F(BadCheckpoint, TruncationIsCaught) {
  for (const size_t length : {size_t{0}, size_t{7}, size_t{39}, size_t{40}, good_.size() / 2, good_.size() - 1}) {
    SCOPED_TRACE("truncated to " + std::to_string(length) + " bytes");
    expect_refused(good_.substr(0, length), length < 8 ? "not a stiffmd checkpoint" : "truncated checkpoint");
  }
}

TEST_F(BadCheckpoint, ANewerOrOlderFormatIsRefused) {
  std::string b = good_;
  const std::uint32_t newer = kCheckpointVersion + 1;
  std::memcpy(b.data() + 12, &newer, 4);
  expect_refused(with_crc(b), "format version " + std::to_string(newer) + " (a newer stiffmd)");
  expect_refused("STFMDCK1" + good_.substr(8), "format version 1 (an older stiffmd)");
  const std::uint32_t two = 2;  // before the Langevin RATTLE state's meaning changed
  std::memcpy(b.data() + 12, &two, 4);
  expect_refused(with_crc(b), "format version 2 (an older stiffmd); this stiffmd reads versions 5 to 8");
  const std::uint32_t three = 3;  // before the exact scene fingerprint: it would read as another scene
  std::memcpy(b.data() + 12, &three, 4);
  expect_refused(with_crc(b), "format version 3 (an older stiffmd); this stiffmd reads versions 5 to 8");
  const std::uint32_t four = 4;  // before the thermostat's heat: the integrator's words would be misread
  std::memcpy(b.data() + 12, &four, 4);
  expect_refused(with_crc(b), "format version 4 (an older stiffmd); this stiffmd reads versions 5 to 8");
}

TEST_F(BadCheckpoint, ACheckpointOfAnotherSceneIsRefused) {
  // The same particles and masses, another ε, another WCA skin or depth, another tether, another box.
  for (const char* set :
       {" --set variables.eps=0.02", " --set forces.excluded_volume.skin=0.25",
        " --set forces.excluded_volume.epsilon=2.5", " --set forces.anchor.k=0.6", " --set build.0.density=0.69"})
    expect_refused(good_, "checkpoint of another scene", set);
  expect_refused(good_, "checkpoint holds 64 particles, the deck 72", " --set build.0.beads=9");
  // Settings a restart may change are not the scene: another method continues (not bit for bit).
  fs::copy(dir_ / "out", dir_ / "copy");
  const auto r =
      cli("run " + melt() + " -o " + (dir_ / "copy").string() +
          " --no-progress --set run.t_end=0.1 --set integrator.method=rattle --set output.thermo_interval=0.01"
          " --restart " +
          (dir_ / "copy" / "checkpoint.bin").string());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("not bit-identical"), std::string::npos) << r.err;
  fs::remove_all(dir_ / "copy");
}

// Ctrl-C on a terminal: the progress bar ends where the run stopped, not at 100 %.
TEST(Progress, ASignalLeavesTheBarWhereTheRunStopped) {
  const fs::path d = test::scratch_dir("progress_sigint");
  // script(1) gives the run a terminal, so that the bar is drawn.
  const std::string cmd = "STIFFMD_SIGNAL_AT_STEP=300:2 script -qec \"" + std::string(STIFFMD_EXE) + " run " + melt() +
                          " -o " + d.string() +
                          " --set integrator.method=velocity-verlet --set integrator.h=0.0005\" " +
                          (d / "typescript").string() + " > /dev/null 2>&1";
  std::system(cmd.c_str());
  const std::string tty = slurp(d / "typescript");
  ASSERT_NE(tty.find("stopped by signal 2 after step 300"), std::string::npos) << tty;
  EXPECT_NE(tty.find("300/1200 steps"), std::string::npos) << tty;
  EXPECT_EQ(tty.find("100.0%"), std::string::npos) << tty;
  fs::remove_all(d);
}

}  // namespace
}  // namespace stiffmd
