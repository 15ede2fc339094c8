#include "engine/domain/domain_integrator.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <limits>
#include <regex>
#include <sstream>

#include "core/errors.hpp"
#include "core/timing.hpp"
#include "engine/domain/ghosted_pairs.hpp"
#include "engine/domain/part_overlaps.hpp"
#include "integrators/clusters.hpp"
#include "integrators/methods.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

struct DomainIntegrator::Part {
  Scene scene;
  std::unique_ptr<Integrator> integrator;
  std::vector<GhostedPairs*> pairs;  // its force field's pair terms
  std::unique_ptr<Thermo> thermo;    // the thermo row's sums of the part (sample_sums)
};

namespace {

// A part's message with its particle numbers ("particle 3", "particles 3 and 4", "particles 3–4",
// "(particles 3, 4)") made the whole system's, as one process would name them: a rank numbers
// its owned and ghost particles 0, 1, … in its part.
std::string with_global_particles(const std::string& what, const std::vector<int>& global_id) {
  static const std::regex numbers("(particles? )([0-9]+)((?: and |–|, )([0-9]+))?");
  std::string out;
  auto global = [&](const std::string& local) {
    const auto i = static_cast<size_t>(std::stoul(local));
    return i < global_id.size() ? std::to_string(global_id[i]) : local;
  };
  auto last = what.cbegin();
  for (std::sregex_iterator m(what.begin(), what.end(), numbers), end; m != end; ++m) {
    out.append(last, what.cbegin() + m->position(0));
    out += (*m)[1].str() + global((*m)[2].str());
    if ((*m)[3].matched) {
      const std::string joined = (*m)[3].str();
      out += joined.substr(0, joined.size() - (*m)[4].length()) + global((*m)[4].str());
    }
    last = what.cbegin() + m->position(0) + m->length(0);
  }
  out.append(last, what.cend());
  return out;
}

// The halo's margin beyond the cutoff: [parallel] halo_margin, else 1.5 × the pair lists' skin. A
// list rebuild keeps the pair sets while no bead has moved (margin − skin)/2 since their selection
// (GhostedPairs); a list rebuilds once a bead moved skin/2, unless its few fast beads (up to the
// skin) miss no pair (NeighborList::needs_rebuild), so at 1.5 skins every rebuild selects again.
// A wider margin keeps some: at 2.5 skins about every other rebuild selects (in.chain on 16 ranks,
// 60 steps: 7 selections for 13 rebuilds), but the wider halo's copies and search cost as much as
// the selections saved (docs/parallel.md, "A pair set kept across list rebuilds"). A margin of the
// skin alone would select before the lists rebuild (16 selections against 11 rebuilds in 60 steps
// of in.chain ×8 on 16 ranks).
double halo_margin(const Scene& sc, double skin, double cutoff) {
  if (sc.parallel.halo_margin > 0.0) return sc.parallel.halo_margin;
  return skin > 0.0 ? 1.5 * skin : 0.3 * cutoff;
}

}  // namespace

void check_parallel_grid(const Scene& sc, int ranks) {
  const Eigen::Vector3i& g = sc.parallel.grid;
  if (g.prod() > 0 && g.prod() != ranks)
    throw InputError(sc.parallel.grid_where + ": " + std::to_string(g.prod()) + " domains (" + std::to_string(g[0]) +
                     " x " + std::to_string(g[1]) + " x " + std::to_string(g[2]) + ") for " + std::to_string(ranks) +
                     " ranks: expected one domain per rank (or no grid: it is chosen)");
}

void check_parallel_outputs(const Scene& sc, int ranks) {
  if (ranks > 1 && !sc.output.state.empty())
    throw InputError(sc.deck_path +
                     ": output.state: the state CSV (one row of 6 N values per frame) is written by one "
                     "process; on " +
                     std::to_string(ranks) +
                     " ranks write positions and velocities with output.h5md (output.h5md_velocity = true)");
}

DomainIntegrator::DomainIntegrator(Scene& whole, const Communicator& comm, std::unique_ptr<Integrator> whole_method)
    : whole_scene_(whole), comm_(comm), whole_(std::move(whole_method)) {
  check_parallel_grid(whole, comm.size());
  domains_ = make_domains();
  evaluations_.assign(whole.forces->num_levels(), 0);
  // What the whole system's numbers need of the deck besides the parts (whole_numbers): the
  // method, and whether its terms conserve momentum (each term's own property, not its particles').
  const MethodInfo* m = find_method(whole.integrator.method);
  rigid_method_ = m->rigid_constraints;
  effective_modes_ = m->effective && whole.forces->stiff_bonds();
  for (const auto& t : whole.forces->terms()) terms_conserve_momentum_ &= t->conserves_momentum();
}

DomainIntegrator::~DomainIntegrator() = default;

std::unique_ptr<Decomposition> DomainIntegrator::make_domains() const {
  const Scene& whole = whole_scene_;
  double cutoff = 0.0, skin = 0.0;
  for (const auto& t : whole.forces->terms())
    if (t->uses_neighbor_list()) cutoff = std::max(cutoff, t->pair_cutoff()), skin = std::max(skin, t->pair_skin());
  const Eigen::Vector3i* dims = whole.parallel.grid.prod() > 0 ? &whole.parallel.grid : nullptr;
  // The box now: a restart's under a barostat (read_checkpoint_for set it on the force field).
  auto domains = std::make_unique<Decomposition>(whole.forces->box(), comm_, cutoff,
                                                 cutoff > 0.0 ? halo_margin(whole, skin, cutoff) : 0.0, dims);
  domains->set_balance(whole.parallel.balance);
  domains->set_halo_pairs_once(whole.parallel.halo_pairs_once);
  return domains;
}

void DomainIntegrator::start_again() {
  if (!part_) throw std::logic_error("DomainIntegrator::start_again: the parts are not distributed yet");
  State& l = part_->scene.state;
  State s;
  s.t = l.t;
  s.step = l.step;
  Eigen::Matrix3Xd x = std::move(l.x), v = std::move(l.v);
  PartMolecules molecules = std::move(molecules_);
  part_.reset();
  domains_ = make_domains();
  std::fill(evaluations_.begin(), evaluations_.end(), 0);
  rebuilds_ = 0;
  reselect_ = box_moved_ = false;
  start_parts(std::move(molecules), std::move(x), std::move(v), s, false);
}

std::vector<double> DomainIntegrator::part_invariants() const {
  const std::vector<double> all = whole_->invariants();
  if (all.empty() || clusters_.empty()) return {};
  std::vector<double> mine;
  for (const Cluster& c : clusters_)
    if (domains_->owns_molecule(c.molecule))
      mine.insert(mine.end(), all.begin() + c.first, all.begin() + c.first + c.modes);
  return mine;
}

// The whole system's numbers from the parts at the start (collective), O(molecules) words at most
// on a rank: the ones one process computes from its whole arrays, to the same values.
void DomainIntegrator::whole_numbers(const Scene& p) {
  const PartMolecules& mine = molecules_;
  const int n = mine.size();
  const StiffBonds* stiff = p.forces->stiff_bonds();
  // csvr's degrees of freedom (degrees_of_freedom, momentum_conserved: integrators/thermostat.hpp)
  // from the particles counted over the ranks: 3 per mobile particle, less 3 when the momentum is
  // conserved (no fixed particle, every term conserving it, no Langevin thermostat) and one per
  // rigid constraint.
  std::int64_t count[4] = {n, 0, 0, stiff ? static_cast<std::int64_t>(stiff->bonds.size()) : 0};
  for (const double w : mine.inv_mass) count[1] += w > 0.0, count[2] += w == 0.0;
  comm_.sum(count, 4);
  whole_n_ = static_cast<int>(count[0]);
  const bool conserved =
      terms_conserve_momentum_ && settings_.thermostat.style != ThermostatSettings::Style::langevin && count[2] == 0;
  whole_dof_ =
      static_cast<int>(3 * count[1] - (conserved && count[1] == count[0] ? 3 : 0) - (rigid_method_ ? count[3] : 0));
  // Whether every topology molecule (its molecule id) lies within one bonded molecule: each (id,
  // bonded molecule) pair of the part goes to the rank id mod ranks, which sees every pair of its
  // ids; one max tells every rank.
  const int ranks = comm_.size();
  std::vector<std::pair<int, int>> pairs;  // (id, the bonded molecule's name)
  for (int k = 0; k < static_cast<int>(mine.molecule_id.size()); ++k)
    if (mine.molecule_id[k] >= 0) pairs.emplace_back(mine.molecule_id[k], domains_->owned_molecule(k));
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  std::vector<std::vector<double>> out(ranks), in;
  for (const auto& [id, molecule] : pairs) out[id % ranks].push_back(id), out[id % ranks].push_back(molecule);
  comm_.exchange(out, in);
  pairs.clear();
  for (const std::vector<double>& b : in)
    for (size_t e = 0; e + 1 < b.size(); e += 2) pairs.emplace_back(static_cast<int>(b[e]), static_cast<int>(b[e + 1]));
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  double split = 0.0;
  for (size_t e = 1; e < pairs.size(); ++e) split = std::max(split, pairs[e].first == pairs[e - 1].first ? 1.0 : 0.0);
  molecules_whole_ = comm_.max(split) == 0.0;
  // The effective dynamics' modes: the constraint clusters as the whole system's find_clusters
  // orders them (integrators/clusters.hpp: by their first bond in the stiff-bond list), one mode
  // per bond. A part's stiff bonds are the whole list's restricted to it, in its order: the bonds
  // of the topology's stiff types first, in the topology's order, then the rigid angles' bonds
  // (engine/scene/force_registry.cpp, read_stiff_harmonic). A cluster's first bond is one of the
  // topology's (a rigid angle's bond is coupled to an arm of its angle, a bond of the topology
  // listed before it), so the clusters take the order of their first bonds' places in the
  // topology's list, which the part's bonds carry (PartMolecules): each rank's (place, modes,
  // molecule) gathered, ordered on rank 0 and broadcast.
  clusters_.clear();
  if (!effective_modes_) return;
  std::vector<double> entries;  // place, modes, molecule per cluster
  if (stiff) {
    // Each stiff bond of the topology at its place: the part's bonds by place, matched in order.
    std::vector<std::int64_t> place(stiff->bonds.size(), -1);
    size_t at = 0;
    for (size_t b = 0; b < stiff->bonds.size() && at < mine.bonds.size(); ++b) {
      const int i = mine.global[stiff->bonds[b].i], j = mine.global[stiff->bonds[b].j];
      size_t e = at;
      while (e < mine.bonds.size() && (mine.bonds[e].item.i != i || mine.bonds[e].item.j != j)) ++e;
      if (e == mine.bonds.size()) break;  // the rigid angles' bonds, past the topology's
      place[b] = mine.bonds[e].place;
      at = e + 1;
    }
    for (const ConstraintCluster& c : find_clusters(stiff->bonds, p.state.inv_mass)) {
      const int first = c.bonds[0];
      if (place[first] < 0)
        throw std::logic_error(
            "DomainIntegrator: a constraint cluster's first stiff bond is not a bond of the topology");
      entries.push_back(static_cast<double>(place[first]));
      entries.push_back(static_cast<double>(c.bonds.size()));
      entries.push_back(domains_->owned_molecule(stiff->bonds[first].i));  // part index = owned column
    }
  }
  std::vector<std::vector<double>> all;
  comm_.gather(entries, all);
  std::vector<double> ordered;
  if (comm_.root()) {
    std::vector<std::array<double, 3>> list;
    for (const std::vector<double>& b : all)
      for (size_t e = 0; e + 2 < b.size(); e += 3) list.push_back({b[e], b[e + 1], b[e + 2]});
    std::sort(list.begin(), list.end());
    for (const auto& c : list) ordered.insert(ordered.end(), {c[2], c[1]});  // molecule, modes
  }
  std::int64_t words = static_cast<std::int64_t>(ordered.size());
  comm_.broadcast(&words, 1);
  ordered.resize(static_cast<size_t>(words));
  comm_.broadcast(ordered.data(), static_cast<int>(words));
  int first = 0;
  for (size_t e = 0; e < ordered.size(); e += 2) {
    const int modes = static_cast<int>(ordered[e + 1]);
    clusters_.push_back({static_cast<int>(ordered[e]), first, modes});
    first += modes;
  }
}

void DomainIntegrator::build_part(Eigen::Matrix3Xd x, Eigen::Matrix3Xd v, const State& s, bool at_start) {
  if (part_) {
    for (int k = 0; k < part_->scene.forces->num_levels(); ++k)
      evaluations_[k] += part_->scene.forces->evaluations(Level{k});
    for (const auto& t : part_->scene.forces->terms()) rebuilds_ += t->neighbor_list_rebuilds();
  }
  const Scene& w = whole_scene_;
  const PartMolecules& mine = molecules_;
  auto part = std::make_unique<Part>();
  Scene& p = part->scene;
  p.deck_path = w.deck_path;
  p.units = w.units;
  p.box = w.forces->box();  // the box now (a barostat moves it)
  p.types = w.types;
  p.integrator = settings_;
  p.run = w.run;
  p.observables = w.observables;
  // The part's particles and bonded items as its molecules carry them (PartMolecules: cut from the
  // whole system at the start, moved with the molecules since), never the whole system's arrays.
  if (mine.global != domains_->owned_ids())
    throw std::logic_error("DomainIntegrator: the part's molecules are not the owned particles");
  p.global_id = mine.global;
  const int n = mine.size();
  p.state.x = std::move(x);
  p.state.v = std::move(v);
  p.state.inv_mass = Eigen::Map<const Eigen::VectorXd>(mine.inv_mass.data(), n);
  p.particle_type = mine.type;
  p.charge = mine.charge;
  p.state.t = s.t;
  p.state.step = s.step;
  // The owned molecules' bonded terms, in the whole system's order (so the constraint clusters,
  // and the effective dynamics' modes, come in the whole system's order too).
  p.topology = mine.topology(w.topology);
  const Topology& t = p.topology;
  ThermostatSettings& th = p.integrator.thermostat;
  if (per_particle_friction_) th.friction = Eigen::Map<const Eigen::VectorXd>(mine.friction.data(), n);
  th.particle_id.assign(p.global_id.begin(), p.global_id.end());
  th.processes = &comm_;
  // A barostat's sums over this rank's molecules, added over the ranks (exactly: the same cell
  // moves on any number of ranks).
  BarostatSettings& baro = p.integrator.barostat;
  if (baro.on) {
    baro.molecule = bonded_molecules(t, n);
    baro.processes = &comm_;
  }
  p.forces = w.forces->on_subset({p.global_id, p.particle_type, t,
                                  charged_ ? std::span<const double>(p.charge) : std::span<const double>(),
                                  std::span<const double>(mine.inv_mass)});
  // The reciprocal sums (k-space terms) sum over the ranks.
  for (const auto& term : p.forces->terms()) term->set_processes(&comm_);
  if (at_start) whole_numbers(p);
  th.degrees_of_freedom = whole_dof_;
  // The pair terms act on the pair set (home beads and halo) through forward and reverse; a part
  // built again keeps the old part's terms on the pair set, and their buffers. What the pair sets
  // read of a bead besides its position comes with it from its owner at each selection
  // (Decomposition::set_owned_pair_data): its type and charge as its molecule carries them, and
  // per pair term its special partners — the part's term made them from its molecules' bonds with
  // the term's weights (on_subset), the whole system's rows of these beads.
  PairBeadData carried;
  carried.type = mine.type;
  for (const auto& term : p.forces->terms())
    if (term->uses_neighbor_list() && term->uses_charges()) carried.charged = true;
  if (carried.charged) carried.charge = mine.charge;
  for (size_t k = 0; k < p.forces->terms().size(); ++k) {
    const ForceTerm& term = *p.forces->terms()[k];
    if (!term.uses_neighbor_list()) continue;
    const auto* on_part = dynamic_cast<const PairsOnParticles*>(&term);
    if (!on_part || k >= w.forces->terms().size() || w.forces->terms()[k]->name() != term.name())
      throw std::logic_error("a part's pair term '" + term.name() + "' is not the whole system's");
    carried.special.push_back(special_partners(on_part->special_pairs(), p.global_id));
    GhostedPairs* old = part_ && part->pairs.size() < part_->pairs.size() ? part_->pairs[part->pairs.size()] : nullptr;
    auto ghosted = std::make_unique<GhostedPairs>(*w.forces->terms()[k], *domains_,
                                                  static_cast<int>(carried.special.size()) - 1, old);
    part->pairs.push_back(ghosted.get());
    p.forces->replace(k, std::move(ghosted));
  }
  domains_->set_owned_pair_data(std::move(carried));
  part->integrator = make_integrator(p.integrator, *p.forces, p.state.inv_mass);
  part->thermo = std::make_unique<Thermo>(*p.forces, p.state.inv_mass, ObservableSettings{}, &p.topology);
  if (std::vector<double> inv = part_invariants(); !inv.empty()) part->integrator->set_invariants(inv);
  part_ = std::move(part);
}

std::string DomainIntegrator::overlaps(const Scene& description) const {
  std::vector<std::string> pair_terms;
  for (const GhostedPairs* term : part_->pairs) pair_terms.push_back(term->name());
  return part_overlaps(description.overlap_rules, pair_terms, *domains_, part_->scene.state.x, part_->scene.box,
                       description, comm_);
}

// The parts take over what the whole-system integrator carries (a restart's cached kick forces,
// or what the first sample left): each its particles' columns, rank 0 the sums.
void DomainIntegrator::start(const State& s) {
  // Each rank cuts a block of the whole system's molecules (any partition of whole molecules
  // would do) and starts from it as a rank that made only its molecules would (start_parts).
  const Scene& w = whole_scene_;
  const Eigen::VectorXd& friction = w.integrator.thermostat.friction;
  PartMolecules block;
  {
    const std::vector<int> mine = whole_block(w.topology, s.size(), comm_.size(), comm_.rank());
    block = cut_part({std::span<const double>(s.inv_mass.data(), static_cast<size_t>(s.inv_mass.size())),
                      w.particle_type, w.charge, w.topology.molecule,
                      std::span<const double>(friction.data(), static_cast<size_t>(friction.size())), w.topology},
                     mine);
  }
  Eigen::Matrix3Xd x(3, block.size()), v(3, block.size());
  for (int k = 0; k < block.size(); ++k) x.col(k) = s.x.col(block.global[k]), v.col(k) = s.v.col(block.global[k]);
  start_parts(std::move(block), std::move(x), std::move(v), s);
}

// The decomposition's start sends each molecule to the rank of its anchor's domain; from then on
// the molecules travel with their data (Decomposition::migrate), and no part reads the whole
// system's arrays again.
void DomainIntegrator::start_parts(PartMolecules molecules, Eigen::Matrix3Xd x, Eigen::Matrix3Xd v, const State& s,
                                   bool carry, const CarriedRows* carried) {
  const Scene& w = whole_scene_;
  molecules_ = std::move(molecules);
  // Over the ranks: whether the particles have a friction each, and whether some has a charge.
  double some[2] = {
      molecules_.friction.empty() ? 0.0 : 1.0,
      std::any_of(molecules_.charge.begin(), molecules_.charge.end(), [](double q) { return q != 0.0; }) ? 1.0 : 0.0};
  comm_.max(some, 2);
  charged_ = some[1] > 0.0;
  domains_->start(molecules_, x, v);
  // The method's settings without their per-particle arrays of the whole system (each part sets
  // its own).
  settings_ = w.integrator;
  per_particle_friction_ = some[0] > 0.0;
  settings_.thermostat.friction.resize(0);
  settings_.thermostat.particle_id.clear();
  settings_.barostat.molecule.clear();
  build_part(std::move(x), std::move(v), s, true);
  // The thermo row's numbers: each part's Thermo counts its topology molecules and the sized ones.
  double polymers[2] = {static_cast<double>(part_->thermo->molecules()),
                        static_cast<double>(part_->thermo->sized_molecules())};
  comm_.sum(polymers, 2);
  thermo_numbers_ = {whole_dof_, polymers[0] > 0.0, polymers[1] > 0.0};
  domains_->select_pair_set(part_->scene.state.x);
  // The lists built now, before the step loop, as one process builds its list in the first
  // force evaluation.
  for (GhostedPairs* term : part_->pairs) term->update_list(part_->scene.state.x, part_->scene.box);
  if (!carry) return;
  CarriedState c = whole_->carried_state();
  // From now on the whole-system integrator holds no column of the whole system: the parts carry
  // them, and a checkpoint hands it columns of one particle for its words (state_block), or the
  // gathered ones on rank 0 (save_state).
  whole_->restore_carried_state(
      {c.flags, c.sums, std::vector<Eigen::Matrix3Xd>(c.columns.size(), Eigen::Matrix3Xd::Zero(3, 1))});
  const std::vector<int>& ids = domains_->owned_ids();
  // A whole scene of descriptions (no particle) was prepared on no particle: its columns are
  // empty, and none of them is valid yet (the first step computes them, as on one process).
  // A restart by parts reads the owned particles' rows of the columns from its checkpoint.
  const bool described = w.state.size() == 0;
  if (carried) {
    if (!described) throw std::logic_error("DomainIntegrator: the rows of the carried columns for a whole scene");
    std::vector<Eigen::Matrix3Xd> rows = (*carried)(ids);
    if (rows.size() != c.columns.size())
      throw std::logic_error("DomainIntegrator: the checkpoint's carried columns are not the integrator's");
    c.columns = std::move(rows);
  } else if (described && std::any_of(c.flags.begin(), c.flags.end(), [](double f) { return f != 0.0; })) {
    throw std::logic_error("DomainIntegrator: a scene of descriptions whose integrator carries valid columns");
  }
  if (!carried)
    for (Eigen::Matrix3Xd& column : c.columns) {
      Eigen::Matrix3Xd mine(3, domains_->num_owned());
      if (described)
        mine.setZero();
      else
        for (int k = 0; k < domains_->num_owned(); ++k) mine.col(k) = column.col(ids[k]);
      column = std::move(mine);
    }
  if (!comm_.root()) std::fill(c.sums.begin(), c.sums.end(), 0.0);
  part_->integrator->restore_carried_state(std::move(c));
  // The parts evaluate the forces from now on: the whole system's terms drop what they can make
  // again (PPPM's whole mesh, which every rank made to prepare and sample the whole scene; rank 0
  // makes it again if it samples the gathered state with the whole field).
  for (const auto& term : whole_scene_.forces->terms()) term->release_buffers();
}

// After the pair sets were selected again (or the box moved): the molecules whose anchors have
// left their domains move, with what the part's integrator carries for their particles (cached
// kick forces, a Langevin force among them: not recomputed, so the run goes on as if nothing had
// moved). Only a part whose particles changed is built again; the pair sets follow any change on
// any rank (each rank's plan names the owners' columns).
void DomainIntegrator::reselect(bool box_moved, const std::vector<Eigen::Matrix3Xd*>& extra) {
  const ScopedPhase phase(Phase::domain);
  State& l = part_->scene.state;
  // The home beads counted at the selection: the dynamic balance may recut the domains first, and
  // the molecules then migrate to the new ones.
  const bool recut = domains_->rebalance(l.x);
  // The integrator's carried columns (its kick forces: a copy of the size of x each) are taken
  // only when a molecule leaves some rank, to travel with it; most selections move none.
  const bool leaving = domains_->molecules_leave(l.x);
  if (leaving) {
    CarriedState carried = part_->integrator->carried_state();
    std::vector<Eigen::Matrix3Xd*> columns;
    for (Eigen::Matrix3Xd& c : carried.columns) columns.push_back(&c);
    columns.insert(columns.end(), extra.begin(), extra.end());
    if (domains_->migrate(l.x, l.v, columns, &molecules_)) {
      Eigen::Matrix3Xd x = std::move(l.x), v = std::move(l.v);
      build_part(std::move(x), std::move(v), l, false);
      part_->integrator->restore_carried_state(std::move(carried));
    }
  }
  if (leaving || box_moved || recut) domains_->select_pair_set(part_->scene.state.x);
}

void DomainIntegrator::step(State& s, double h) {
  if (!part_)
    start(s);
  else if (reselect_ || box_moved_)
    reselect(box_moved_);
  reselect_ = box_moved_ = false;
  const long selections = domains_->selections();
  State& l = part_->scene.state;
  l.step = s.step;
  l.t = s.t;
  try {
    part_->integrator->step(l, h);
  } catch (const NumericalError& e) {  // this rank's alone (engine/main.cpp ends the job)
    throw NumericalError(with_global_particles(e.what(), part_->scene.global_id));
  }
  // A barostat moved the cell (every rank alike, at the same step): the domains, the whole
  // system's box (checkpoints, outputs) and the pair sets follow it before the next step.
  if (const Box& box = part_->scene.forces->box(); box.lengths != domains_->box().lengths) {
    domains_->set_box(box);
    whole_scene_.forces->set_box(box);
    box_moved_ = true;
  }
  // The pair sets were selected again in this step (every rank alike): the molecules whose anchor
  // left their domain move before the next.
  reselect_ = domains_->selections() != selections;
  // One reduction: the first particle (global index) with a non-finite position or velocity.
  const int bad = domains_->first_non_finite(l.x, l.v);
  double first_bad =
      bad >= 0 ? -static_cast<double>(part_->scene.global_id[bad]) : -std::numeric_limits<double>::infinity();
  {
    const ScopedPhase phase(Phase::domain);
    comm_.max(&first_bad, 1);
  }
  if (std::isfinite(first_bad)) {
    std::ostringstream m;
    m << "numerical failure: non-finite position or velocity of particle " << static_cast<long>(-first_bad);
    throw AgreedStop(m.str(), comm_.root());
  }
}

void DomainIntegrator::reset() {
  whole_->reset();
  if (part_) part_->integrator->reset();
}

double DomainIntegrator::model_potential(const Eigen::Matrix3Xd& x) {
  if (!part_) return whole_->model_potential(x);
  return comm_.sum(part_->integrator->model_potential(part_->scene.state.x));
}

double DomainIntegrator::constraint_virial(const State& s) {
  if (!part_) return whole_->constraint_virial(s);
  return comm_.sum(part_->integrator->constraint_virial(part_->scene.state));
}

double DomainIntegrator::kinetic_energy_estimate(const State& s) const {
  if (!part_) return whole_->kinetic_energy_estimate(s);
  return comm_.sum(part_->integrator->kinetic_energy_estimate(part_->scene.state));
}

// Each rank's thermostat acts on its own particles, and their heats add up (csvr's too: each
// rank counts (α² − 1) times its particles' kinetic energy).
double DomainIntegrator::thermostat_heat() const {
  if (!part_) return whole_->thermostat_heat();
  return comm_.sum(part_->integrator->thermostat_heat());
}

std::vector<double> DomainIntegrator::save_state() const {
  if (!part_) return whole_->save_state();
  // The whole system's state: the parts' columns by global index, their sums added, the flags
  // (alike on every rank) and the invariants as they are.
  CarriedState c = part_->integrator->carried_state();
  if (!c.sums.empty()) comm_.sum(c.sums.data(), static_cast<int>(c.sums.size()));
  std::vector<Eigen::Matrix3Xd> whole_columns;
  domains_->gather_columns(c.columns, whole_columns, whole_n_);
  if (!comm_.root()) return {};
  c.columns = std::move(whole_columns);
  whole_->restore_carried_state(std::move(c));
  return whole_->save_state();
}

namespace {

// Where save_state() puts each carried column: the whole-system integrator restores columns of one
// particle whose three words are marks — quiet NaNs whose payload names the column and the row,
// never a word an integrator keeps (positions, forces, sums, flags and counts are numbers) — and
// the marks in its words are the columns' places, the words between them its own.
constexpr std::uint64_t kColumnMark = 0x7ff8'5354'0000'0000ull;

double column_mark(std::size_t column, int row) {
  return std::bit_cast<double>(kColumnMark | (static_cast<std::uint64_t>(column) << 2) |
                               static_cast<std::uint64_t>(row));
}

std::vector<WordRun> word_runs(const std::vector<double>& words, std::size_t columns) {
  std::vector<WordRun> runs;
  std::vector<char> seen(columns, 0);
  for (std::size_t i = 0; i < words.size();) {
    const auto bits = std::bit_cast<std::uint64_t>(words[i]);
    if ((bits >> 32) != (kColumnMark >> 32)) {
      if (runs.empty() || runs.back().column >= 0) runs.emplace_back();
      runs.back().words.push_back(words[i++]);
      continue;
    }
    const std::size_t column = (bits & 0xffff'ffffull) >> 2;
    bool whole = column < columns && !seen[column] && i + 3 <= words.size();
    for (int row = 0; whole && row < 3; ++row)
      whole = std::bit_cast<std::uint64_t>(words[i + row]) == std::bit_cast<std::uint64_t>(column_mark(column, row));
    if (!whole) throw std::logic_error("save_state: a carried column not as one run of its particles' words");
    seen[column] = 1;
    runs.push_back({{}, static_cast<int>(column)});
    i += 3;
  }
  if (std::find(seen.begin(), seen.end(), 0) != seen.end())
    throw std::logic_error("save_state: a carried column missing from the integrator's words");
  return runs;
}

}  // namespace

std::vector<WordRun> DomainIntegrator::word_layout() const {
  if (part_) throw std::logic_error("DomainIntegrator::word_layout: after the start");
  CarriedState now = whole_->carried_state();
  CarriedState marked = now;
  for (std::size_t k = 0; k < marked.columns.size(); ++k) {
    marked.columns[k].resize(3, 1);
    for (int row = 0; row < 3; ++row) marked.columns[k](row, 0) = column_mark(k, row);
  }
  whole_->restore_carried_state(std::move(marked));
  std::vector<WordRun> runs = word_runs(whole_->save_state(), now.columns.size());
  whole_->restore_carried_state(std::move(now));
  return runs;
}

StateBlock DomainIntegrator::state_block(const State& whole) const {
  StateBlock b;
  const int n = part_ ? whole_n_ : whole.size();
  b.block = block_of(n, comm_.size(), comm_.rank());
  if (!part_) {
    b.x = whole.x.data() + 3 * b.block.first;
    b.v = whole.v.data() + 3 * b.block.first;
    b.inv_mass = whole.inv_mass.data() + b.block.first;
    b.words.push_back({whole_->save_state(), -1});
    return b;
  }
  // As save_state: the parts' sums added (the same on every rank), their columns by global index.
  // The part's own arrays go to the writer as they are (it brings them to the blocks by rounds).
  CarriedState c = part_->integrator->carried_state();
  if (!c.sums.empty()) comm_.sum(c.sums.data(), static_cast<int>(c.sums.size()));
  const State& mine = part_->scene.state;
  b.x = mine.x.data();
  b.v = mine.v.data();
  b.inv_mass = mine.inv_mass.data();
  b.owned = &domains_->owned_ids();
  const std::size_t columns = c.columns.size();
  b.columns = std::move(c.columns);
  c.columns.assign(columns, Eigen::Matrix3Xd(3, 1));
  for (std::size_t k = 0; k < columns; ++k)
    for (int row = 0; row < 3; ++row) c.columns[k](row, 0) = column_mark(k, row);
  whole_->restore_carried_state(std::move(c));
  b.words = word_runs(whole_->save_state(), columns);
  return b;
}

void DomainIntegrator::gather(State& whole) const {
  if (!part_) return;
  // A state without the whole system's inverse masses (a scene of descriptions holds none, on
  // every rank alike) gets them too, as the first row of a third column.
  const State& l = part_->scene.state;
  if (whole.inv_mass.size() == whole_n_) {
    domains_->gather_columns({&l.x, &l.v}, {&whole.x, &whole.v}, whole_n_);
    return;
  }
  Eigen::Matrix3Xd mine = Eigen::Matrix3Xd::Zero(3, l.size()), all;
  mine.row(0) = l.inv_mass.transpose();
  domains_->gather_columns({&l.x, &l.v, &mine}, {&whole.x, &whole.v, &all}, whole_n_);
  if (comm_.root()) whole.inv_mass = all.row(0).transpose();
}

std::vector<std::int64_t> DomainIntegrator::evaluations() const {
  std::vector<std::int64_t> e = evaluations_;
  if (part_)
    for (int k = 0; k < part_->scene.forces->num_levels(); ++k) e[k] += part_->scene.forces->evaluations(Level{k});
  return e;
}

long DomainIntegrator::neighbor_rebuilds() const {
  long r = rebuilds_;
  if (part_)
    for (const auto& t : part_->scene.forces->terms()) r += t->neighbor_list_rebuilds();
  return r;
}

DomainReport DomainIntegrator::report() const {
  DomainReport r;
  r.ranks = comm_.size();
  if (!part_) return r;
  r.grid = domains_->grid().dims;
  const double home = domains_->num_home();
  const double halo = static_cast<double>(domains_->pair_ids().size()) - home;
  std::int64_t listed = 0;
  for (const auto& t : part_->scene.forces->terms()) listed += t->listed_pairs();
  double v[6] = {halo,
                 home,
                 8.0 * static_cast<double>(domains_->halo_doubles()),
                 static_cast<double>(domains_->halo_messages()),
                 static_cast<double>(domains_->migrated_molecules()),
                 static_cast<double>(listed)};
  comm_.sum(v, 6);
  r.halo_pairs_once = domains_->halo_pairs_once();
  r.ghosts_per_owned = v[1] > 0.0 ? v[0] / v[1] : 0.0;
  r.halo_bytes_per_step = v[2];
  r.halo_messages_per_step = v[3];
  r.migrated_molecules = static_cast<long>(v[4]);
  r.neighbor_pairs = static_cast<std::int64_t>(v[5]);
  r.redistributions = domains_->selections() - 1;
  // The ranks rebuild their lists together (GhostedPairs), so the fewest and the most agree.
  double rebuilds[2] = {-static_cast<double>(neighbor_rebuilds()), static_cast<double>(neighbor_rebuilds())};
  comm_.max(rebuilds, 2);
  r.neighbor_rebuilds_min = static_cast<long>(-rebuilds[0]);
  r.neighbor_rebuilds_max = static_cast<long>(rebuilds[1]);
  double whole_listed = 0.0;
  for (const auto& t : whole_scene_.forces->terms()) whole_listed += static_cast<double>(t->listed_pairs());
  double held[2] = {static_cast<double>(domains_->pair_ids().size()), whole_listed};
  comm_.max(held, 2);
  r.particles = whole_n_;
  r.pair_set_max = static_cast<long>(held[0]);
  r.whole_list_pairs_max = static_cast<std::int64_t>(held[1]);
  r.imbalance_before = domains_->imbalance_before();
  r.imbalance_after = domains_->imbalance(part_->scene.state.x);
  r.recuts = domains_->recuts();
  for (int a = 0; a < 3; ++a) {
    const DomainGrid& g = domains_->grid();
    r.cuts[a].resize(g.dims[a] + 1);
    for (int c = 0; c <= g.dims[a]; ++c)
      r.cuts[a][c] = g.cut[a].empty() ? static_cast<double>(c) / g.dims[a] : g.cut[a][c];
  }
  return r;
}

const State& DomainIntegrator::owned_state() const {
  return part_->scene.state;
}

const Scene& DomainIntegrator::part_scene() const {
  return part_->scene;
}

Scene& DomainIntegrator::mutable_part_scene() {
  return part_->scene;
}

std::string DomainIntegrator::in_whole_numbers(const std::string& what) const {
  static const std::regex bond("stiff bond [0-9]+ \\(");
  return with_global_particles(std::regex_replace(what, bond, "a stiff bond ("), part_->scene.global_id);
}

void DomainIntegrator::owned_forces(Eigen::Matrix3Xd& f) const {
  part_->scene.forces->total_force(part_->scene.state.x, f);
}

ThermoSums DomainIntegrator::sample_sums() const {
  ThermoSums sums = part_->thermo->sums(part_->scene.state);
  sums.level_energy.resize(whole_scene_.forces->num_levels(), 0.0);
  std::vector<double> flat = sums.flat();
  comm_.sum(flat.data(), static_cast<int>(flat.size()));
  comm_.max(&sums.max_violation, 1);
  sums.set_flat(flat);
  return sums;
}

}  // namespace stiffmd
