#include "engine/run/summary.hpp"

#include <cstdio>
#include <sstream>

#include "core/parallel.hpp"

namespace stiffmd {

std::string format_summary(const RunSummary& s) {
  std::ostringstream o;
  o.precision(6);
  o << "method:        " << s.method << " (h = " << s.h;
  if (s.micro_steps > 1) o << ", " << s.micro_steps << " micro steps of " << s.h / s.micro_steps;
  o << ")\n";
  o << "steps:         " << s.steps << " to t = " << s.t_end << " in " << s.wall_seconds << " s wall\n";
  o << "force evals:   ";
  if (s.level_evaluations.size() > 2) {
    for (size_t k = s.level_evaluations.size(); k-- > 0;)
      o << s.level_evaluations[k].second << " " << s.level_evaluations[k].first << (k ? ", " : "");
  } else {
    o << s.slow_evaluations << " slow, " << s.fast_evaluations << " fast";
  }
  if (s.neighbor_rebuilds >= 0) o << "; " << s.neighbor_rebuilds << " neighbour-list rebuilds";
  o << "\n";
  if (!s.thermostat) {
    const double rel = s.initial_energy != 0.0 ? s.max_energy_error / std::abs(s.initial_energy) : s.max_energy_error;
    o << "energy:        E(0) = " << s.initial_energy << ", E(end) = " << s.final_energy
      << ", max |E - E(0)| = " << s.max_energy_error << " (relative " << rel << ")\n";
  } else {
    // E exchanges heat with the bath: what tells the step's error is E + ecouple, the energy with
    // the heat the thermostat took, and its drift per particle and time (GROMACS's "conserved
    // energy drift", LAMMPS's econserve).
    o << "energy:        E(0) = " << s.initial_energy << ", E(end) = " << s.final_energy
      << " (not conserved: the thermostat exchanges heat)\n";
    o << "conserved:     E + ecouple: E_c(end) - E_c(0) = " << s.final_conserved_energy - s.initial_conserved_energy
      << ", drift " << s.conserved_energy_drift
      << (s.units == "real" ? " kcal/mol per atom per fs" : " per particle per time unit")
      << " (/ N t, N = " << s.particles << "), max |E_c - E_c(0)| = " << s.max_conserved_error << "\n";
  }
  if (!s.final_actions.empty()) {
    o << "actions:       ";
    for (size_t k = 0; k < s.final_actions.size(); ++k)
      o << (k ? ", " : "") << "I_" << k + 1 << " " << s.initial_actions[k] << " -> " << s.final_actions[k];
    o << "\n";
  }
  if (s.phase_seconds.empty()) {
    o << "timing:        step loop " << s.loop_seconds << " s wall on " << s.threads
      << (s.threads == 1 ? " thread" : " threads") << "; by phase from " << kParallelMin
      << " particles on, or with a k-space term (a smaller step is too short to time by parts)\n";
  } else if (s.loop_seconds > 0.0) {
    o << "timing:        step loop " << s.loop_seconds << " s wall on " << s.threads
      << (s.threads == 1 ? " thread" : " threads");
    if (s.serial_share >= 0.0) o << ", serial share " << 100.0 * s.serial_share << " % (outside the parallel loops)";
    o << "\n";
    char line[96];
    for (size_t k = 0; k < s.phase_seconds.size(); ++k) {
      std::snprintf(line, sizeof line, "  %-13s %10.4f s %6.1f %%", std::string(kPhaseNames[k]).c_str(),
                    s.phase_seconds[k], 100.0 * s.phase_seconds[k] / s.loop_seconds);
      o << "             " << line;
      if (k < s.rank_phase_seconds_max.size()) {  // rank 0's; the ranks' mean and max
        std::snprintf(line, sizeof line, "   ranks: mean %.4f s, max %.4f s", s.rank_phase_seconds_mean[k],
                      s.rank_phase_seconds_max[k]);
        o << line;
      }
      o << "\n";
    }
  }
  if (s.domains.ranks > 1) {
    const DomainReport& d = s.domains;
    o << "ranks:         " << d.ranks << " (domains " << d.grid[0] << " x " << d.grid[1] << " x " << d.grid[2]
      << "), step loop max " << s.rank_loop_seconds_max << " s, mean " << s.rank_loop_seconds_mean << " s; "
      << d.ghosts_per_owned << " halo beads per home bead" << (d.halo_pairs_once ? " (their pairs once)" : "")
      << ", halo " << d.halo_bytes_per_step << " bytes in " << d.halo_messages_per_step << " messages; "
      << d.redistributions << " redistributions moved " << d.migrated_molecules << " molecules; home beads max/mean "
      << d.imbalance_before << " on equal slabs at the start, " << d.imbalance_after << " at the end (" << d.recuts
      << (d.recuts == 1 ? " recut)" : " recuts)");
    if (s.h5md_writers > 0) o << "; H5MD written by " << s.h5md_writers << (s.h5md_writers > 1 ? " ranks" : " rank");
    o << "\n";
  }
  {
    char line[160];
    if (s.domains.ranks > 1)
      std::snprintf(line, sizeof line,
                    "memory:        peak resident set %.0f MiB (rank 0), ranks: max %.0f MiB, mean %.0f MiB\n",
                    s.peak_rss_mib, s.rank_peak_rss_mib_max, s.rank_peak_rss_mib_mean);
    else
      std::snprintf(line, sizeof line, "memory:        peak resident set %.0f MiB\n", s.peak_rss_mib);
    o << line;
    if (s.setup_seconds >= 0.0) {
      if (s.domains.ranks > 1)
        std::snprintf(line, sizeof line, "set-up:        %.3f s (rank 0), ranks: max %.3f s, mean %.3f s\n",
                      s.setup_seconds, s.rank_setup_seconds_max, s.rank_setup_seconds_mean);
      else
        std::snprintf(line, sizeof line, "set-up:        %.3f s\n", s.setup_seconds);
      o << line;
    }
  }
  o << "outputs:       ";
  for (size_t k = 0; k < s.outputs.size(); ++k) o << (k ? "\n               " : "") << s.outputs[k];
  o << "\n";
  return o.str();
}

std::string summary_json(const RunSummary& s) {
  std::ostringstream o;
  o.precision(17);
  auto list = [&](const std::vector<double>& v) {
    o << "[";
    for (size_t k = 0; k < v.size(); ++k) o << (k ? ", " : "") << v[k];
    o << "]";
  };
  o << "{\n";
  if (s.stage.staged())  // the stage's number (1..) and name among the protocol's (engine/run/stages.hpp)
    o << "  \"stage\": {\"number\": " << s.stage.number << ", \"of\": " << s.stage.count << ", \"name\": \""
      << s.stage.name << "\"},\n";
  o << "  \"method\": \"" << s.method << "\",\n  \"units\": \"" << s.units << "\",\n  \"h\": " << s.h
    << ",\n  \"micro_steps\": " << s.micro_steps << ",\n  \"epsilon\": " << s.epsilon << ",\n  \"steps\": " << s.steps
    << ",\n  \"t_end\": " << s.t_end << ",\n  \"wall_seconds\": " << s.wall_seconds
    << ",\n  \"cpu_seconds\": " << s.cpu_seconds << ",\n  \"peak_rss_mib\": " << s.peak_rss_mib;
  if (s.setup_seconds >= 0.0) o << ",\n  \"setup_seconds\": " << s.setup_seconds;
  o << ",\n  \"neighbor_rebuilds\": " << s.neighbor_rebuilds << ",\n  \"neighbor_pairs\": " << s.neighbor_pairs
    << ",\n  \"slow_evaluations\": " << s.slow_evaluations << ",\n  \"fast_evaluations\": " << s.fast_evaluations
    << ",\n  \"level_evaluations\": {";
  for (size_t k = 0; k < s.level_evaluations.size(); ++k)
    o << (k ? ", " : "") << "\"" << s.level_evaluations[k].first << "\": " << s.level_evaluations[k].second;
  o << "}"
    << ",\n  \"initial_energy\": " << s.initial_energy << ",\n  \"final_energy\": " << s.final_energy
    << ",\n  \"max_energy_error\": " << s.max_energy_error
    << ",\n  \"initial_conserved_energy\": " << s.initial_conserved_energy
    << ",\n  \"final_conserved_energy\": " << s.final_conserved_energy
    << ",\n  \"max_conserved_energy_error\": " << s.max_conserved_error
    << ",\n  \"conserved_energy_drift\": " << s.conserved_energy_drift
    << ",\n  \"final_max_violation\": " << s.final_max_violation << ",\n  \"initial_actions\": ";
  list(s.initial_actions);
  o << ",\n  \"final_actions\": ";
  list(s.final_actions);
  o << ",\n  \"threads\": " << s.threads << ",\n  \"loop_seconds\": " << s.loop_seconds << ",\n  \"timing\": {";
  for (size_t k = 0; k < s.phase_seconds.size(); ++k)
    o << (k ? ", " : "") << "\"" << kPhaseNames[k] << "\": " << s.phase_seconds[k];
  o << "},\n  \"serial_share\": ";
  if (s.serial_share >= 0.0)
    o << s.serial_share;
  else
    o << "null";
  if (s.minimize) {
    const MinimizeReport& m = *s.minimize;
    o << ",\n  \"minimize\": {\"style\": \"" << style_name(m.style) << "\", \"stopped_by\": \"" << m.stopped_by
      << "\", \"iterations\": " << m.iterations << ", \"evaluations\": " << m.evaluations
      << ", \"initial_energy\": " << m.initial_energy << ", \"energy\": " << m.energy << ", \"fmax\": " << m.fmax
      << ", \"fnorm\": " << m.fnorm << ", \"max_violation\": " << m.max_violation << "}";
  }
  if (s.domains.ranks > 1) {
    const DomainReport& d = s.domains;
    o << ",\n  \"ranks\": " << d.ranks << ",\n  \"domains\": {\"setup\": \"" << s.domain_setup << "\", \"scene\": \""
      << s.domain_scene << "\", \"grid\": [" << d.grid[0] << ", " << d.grid[1] << ", " << d.grid[2]
      << "], \"rank_loop_seconds_mean\": " << s.rank_loop_seconds_mean
      << ", \"rank_loop_seconds_max\": " << s.rank_loop_seconds_max
      << ", \"exchange_seconds_mean\": " << s.rank_exchange_seconds_mean
      << ", \"exchange_seconds_max\": " << s.rank_exchange_seconds_max
      << ", \"reduction_seconds_mean\": " << s.rank_reduction_seconds_mean
      << ", \"reduction_seconds_max\": " << s.rank_reduction_seconds_max << ", \"halo_pairs\": \""
      << (d.halo_pairs_once ? "once" : "both") << "\""
      << ", \"ghosts_per_owned\": " << d.ghosts_per_owned << ", \"halo_bytes_per_step\": " << d.halo_bytes_per_step
      << ", \"halo_messages_per_step\": " << d.halo_messages_per_step << ", \"redistributions\": " << d.redistributions
      << ", \"migrated_molecules\": " << d.migrated_molecules
      << ", \"neighbor_rebuilds_min\": " << d.neighbor_rebuilds_min
      << ", \"neighbor_rebuilds_max\": " << d.neighbor_rebuilds_max << ", \"particles\": " << d.particles
      << ", \"pair_set_max\": " << d.pair_set_max << ", \"whole_list_pairs_max\": " << d.whole_list_pairs_max
      << ", \"h5md_writers\": " << s.h5md_writers << ", \"peak_rss_mib_mean\": " << s.rank_peak_rss_mib_mean
      << ", \"peak_rss_mib_max\": " << s.rank_peak_rss_mib_max;
    if (s.setup_seconds >= 0.0)
      o << ", \"setup_seconds_mean\": " << s.rank_setup_seconds_mean
        << ", \"setup_seconds_max\": " << s.rank_setup_seconds_max;
    o << ", \"imbalance_before\": " << d.imbalance_before << ", \"imbalance_after\": " << d.imbalance_after
      << ", \"recuts\": " << d.recuts << ", \"cuts\": [";
    for (int a = 0; a < 3; ++a) {
      o << (a ? ", [" : "[");
      for (size_t c = 0; c < d.cuts[a].size(); ++c) o << (c ? ", " : "") << d.cuts[a][c];
      o << "]";
    }
    o << "]";
    for (const auto& [name, seconds] :
         {std::pair{"timing_mean", &s.rank_phase_seconds_mean}, std::pair{"timing_max", &s.rank_phase_seconds_max}}) {
      if (seconds->empty()) continue;
      o << ", \"" << name << "\": {";
      for (size_t k = 0; k < seconds->size(); ++k)
        o << (k ? ", " : "") << "\"" << kPhaseNames[k] << "\": " << (*seconds)[k];
      o << "}";
    }
    o << "}";
  }
  o << "\n}\n";
  return o.str();
}

}  // namespace stiffmd
