// The pair loop alone on a deck's initial state: each neighbour-list term's full pass
// (ForceTerm::add_forces: forces and energy, every listed pair evaluated and masked) against its
// force-only pass (add_forces_only: the interacting pairs alone, no sums), interleaved repeats on
// one thread, with a check that the two give the same forces bit for bit. Prints the median
// seconds per evaluation and ns per listed pair of each, and their ratio. For an `lj` or `wca`
// term of one particle type, then the force-only pass (pair_loop.hpp, accumulate_pair_forces_rows)
// with its scalar passes against its AVX2 ones (where the CPU has them: the separations, the
// kernel, the scatter), called directly on the term's list: CPU time per call, and whether the
// forces are the same bits.
//
//   OMP_NUM_THREADS=1 build/tools/benchmarks/stiffmd_pair_loop inputs/kremer_grest.toml [repeats] [calls]
//
// The list is built once at the initial positions, so the loop times the pair loop alone (the
// wrap of the positions into the box included, as the pair phase of a run counts it).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <sstream>
#include <string>
#include <vector>

#include <ctime>

#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/pair_term.hpp"

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

double cpu_seconds() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

// accumulate_pair_forces_rows's scalar and AVX2 passes on the term's list (one type);
// returns whether their forces are the same bits. False when the term is not of this kernel.
template <class Kernel>
bool compare_first_passes(const stiffmd::ForceTerm& t, const Eigen::Matrix3Xd& x, const stiffmd::Box& box, int repeats,
                          int calls, bool& same) {
  using namespace stiffmd;
  const auto* term = dynamic_cast<const PairTerm<Kernel>*>(&t);
  if (!term || term->coeffs().num_types() != 1 || !box.any_periodic()) return false;
  NeighborList list = term->neighbor_list();  // built by the calls before
  const auto params = term->coeffs().transform([](const typename Kernel::Coeffs& c) { return Kernel::params(c); });
  const int n = static_cast<int>(x.cols());
  const std::vector<int> type(n, 0);
  const Eigen::Matrix3Xd& xw = list.wrapped_positions(x);
  const NearestImage near(box, list.cutoff() + list.skin());
  Eigen::Matrix3Xd f[2] = {Eigen::Matrix3Xd::Zero(3, n), Eigen::Matrix3Xd::Zero(3, n)};
  for (int v = 0; v < 2; ++v)
    accumulate_pair_forces_rows<Kernel, true, true>(list, 0, n, params, type.data(), 0, xw, near, f[v].data(), {},
                                                    v == 1);
  same = std::memcmp(f[0].data(), f[1].data(), sizeof(double) * f[0].size()) == 0;
  std::vector<double> t_pass[2];
  for (int r = 0; r < repeats; ++r)
    for (int v = 0; v < 2; ++v) {
      const double start = cpu_seconds();
      for (int c = 0; c < calls; ++c)
        accumulate_pair_forces_rows<Kernel, true, true>(list, 0, n, params, type.data(), 0, xw, near, f[v].data(), {},
                                                        v == 1);
      t_pass[v].push_back((cpu_seconds() - start) / calls);
    }
  const double a = median(t_pass[0]), b = median(t_pass[1]);
  std::printf(
      "  force-only passes scalar %.4f ms, AVX2 %.4f ms (CPU time; AVX2 %s): AVX2 / scalar %.3f; bit-identical: %s\n",
      1e3 * a, 1e3 * b, pair_loop_avx2() ? "on this CPU" : "absent: both scalar", b / a, same ? "yes" : "NO");
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace stiffmd;
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s DECK [repeats = 7] [calls per repeat = 50]\n", argv[0]);
    return 2;
  }
  const int repeats = argc > 2 ? std::atoi(argv[2]) : 7;
  const int calls = argc > 3 ? std::atoi(argv[3]) : 50;
  try {
    Scene scene = load_scene(Deck(argv[1], {}));
    std::ostringstream log;
    prepare_scene(scene, log);
    const Eigen::Matrix3Xd& x = scene.state.x;
    const Box& box = scene.forces->box();
    int status = 0;
    for (const auto& term : scene.forces->terms()) {
      if (!term->uses_neighbor_list()) continue;
      Eigen::Matrix3Xd full = Eigen::Matrix3Xd::Zero(3, x.cols()), only = full;
      term->add_forces(x, box, full);  // builds the list
      term->add_forces_only(x, box, only);
      const bool same = std::memcmp(full.data(), only.data(), sizeof(double) * full.size()) == 0;
      const double pairs = static_cast<double>(term->listed_pairs());
      std::vector<double> t_full, t_only;
      Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
      for (int r = 0; r < repeats; ++r)
        for (int which = 0; which < 2; ++which) {
          const auto start = std::chrono::steady_clock::now();
          double sink = 0.0;
          for (int c = 0; c < calls; ++c) {
            if (which == 0)
              sink += term->add_forces(x, box, f);
            else
              term->add_forces_only(x, box, f);
          }
          const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() / calls;
          (which == 0 ? t_full : t_only).push_back(s);
          if (sink == 12345.678) std::puts("");  // keeps the energy live
        }
      const double a = median(t_full), b = median(t_only);
      std::printf("%s (%s): %d particles, %.0f listed pairs, %d repeats of %d calls\n", term->name().c_str(),
                  std::string(term->style()).c_str(), static_cast<int>(x.cols()), pairs, repeats, calls);
      std::printf("  add_forces       %.4f ms  %.3f ns/listed pair\n", 1e3 * a, 1e9 * a / pairs);
      std::printf("  add_forces_only  %.4f ms  %.3f ns/listed pair\n", 1e3 * b, 1e9 * b / pairs);
      std::printf("  force-only / full %.3f; forces bit-identical: %s\n", b / a, same ? "yes" : "NO");
      if (!same) status = 1;
      bool passes_same = true;
      if (compare_first_passes<LennardJones>(*term, x, box, repeats, calls, passes_same) ||
          compare_first_passes<WeeksChandlerAndersen>(*term, x, box, repeats, calls, passes_same))
        if (!passes_same) status = 1;
    }
    return status;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
}
