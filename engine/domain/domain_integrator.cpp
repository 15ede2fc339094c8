#include "engine/domain/domain_integrator.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include "engine/core/errors.hpp"
#include "engine/core/timing.hpp"
#include "integrators/methods.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

struct DomainIntegrator::Part {
  Scene scene;
  std::unique_ptr<Integrator> integrator;
};

namespace {

// The halo's margin beyond the cutoff: [parallel] halo_margin, else twice the pair lists' skin
// (a redistribution when some bead may have moved a skin, about as often as one process rebuilds
// its list: each redistribution builds the part and its lists anew).
double halo_margin(const Scene& sc, double skin) {
  if (sc.parallel.halo_margin > 0.0) return sc.parallel.halo_margin;
  return skin > 0.0 ? 2.0 * skin : 0.6;
}

}  // namespace

DomainIntegrator::DomainIntegrator(Scene& whole, const Deck& deck, const Communicator& comm,
                                   std::unique_ptr<Integrator> whole_method)
    : whole_scene_(whole), deck_(deck), comm_(comm), whole_(std::move(whole_method)) {
  double cutoff = 0.0, skin = 0.0;
  for (const auto& t : whole.forces->terms())
    if (t->uses_neighbor_list()) cutoff = std::max(cutoff, t->pair_cutoff()), skin = std::max(skin, t->pair_skin());
  const Eigen::Vector3i* dims = whole.parallel.grid.prod() > 0 ? &whole.parallel.grid : nullptr;
  domains_ = std::make_unique<Decomposition>(whole.topology, whole.state.inv_mass, whole.box, comm, cutoff,
                                             cutoff > 0.0 ? halo_margin(whole, skin) : 0.0, dims);
  evaluations_.assign(whole.forces->num_levels(), 0);
  const MethodInfo* m = find_method(whole.integrator.method);
  const StiffBonds* stiff = whole.forces->stiff_bonds();
  const int rigid = m->rigid_constraints && stiff ? static_cast<int>(stiff->bonds.size()) : 0;
  const Eigen::VectorXd& im = whole.state.inv_mass;
  whole_dof_ = degrees_of_freedom(im, momentum_conserved(*whole.forces, im, whole.integrator.thermostat), rigid);
  if (m->effective && stiff) {
    // Clusters of the stiff bonds (union–find on the particles), in the order of their first bond.
    std::vector<int> parent(im.size());
    std::iota(parent.begin(), parent.end(), 0);
    const auto find = [&](int i) {
      while (parent[i] != i) i = parent[i] = parent[parent[i]];
      return i;
    };
    for (const StiffBond& b : stiff->bonds) parent[find(b.i)] = find(b.j);
    std::vector<int> cluster_of_root(im.size(), -1);
    for (const StiffBond& b : stiff->bonds) {
      int& c = cluster_of_root[find(b.i)];
      if (c < 0) c = static_cast<int>(clusters_.size()), clusters_.push_back({domains_->molecule_of(b.i), 0, 0});
      ++clusters_[c].modes;
    }
    for (size_t c = 1; c < clusters_.size(); ++c) clusters_[c].first = clusters_[c - 1].first + clusters_[c - 1].modes;
  }
}

DomainIntegrator::~DomainIntegrator() = default;

std::vector<double> DomainIntegrator::part_invariants() const {
  const std::vector<double> all = whole_->invariants();
  if (all.empty() || clusters_.empty()) return {};
  std::vector<double> mine;
  for (const Cluster& c : clusters_)
    if (domains_->owns_molecule(c.molecule))
      mine.insert(mine.end(), all.begin() + c.first, all.begin() + c.first + c.modes);
  return mine;
}

void DomainIntegrator::build_part(Eigen::Matrix3Xd x, Eigen::Matrix3Xd v, const State& s) {
  if (part_) {
    for (int k = 0; k < part_->scene.forces->num_levels(); ++k)
      evaluations_[k] += part_->scene.forces->evaluations(Level{k});
    for (const auto& t : part_->scene.forces->terms()) rebuilds_ += t->neighbor_list_rebuilds();
  }
  const Scene& w = whole_scene_;
  const Decomposition& d = *domains_;
  auto part = std::make_unique<Part>();
  Scene& p = part->scene;
  p.deck_path = w.deck_path;
  p.units = w.units;
  p.box = w.box;
  p.types = w.types;
  p.integrator = w.integrator;
  p.run = w.run;
  p.observables = w.observables;
  p.global_id = d.local_ids();
  const int n = d.num_local();
  p.state.x = std::move(x);
  p.state.v = std::move(v);
  p.state.inv_mass.resize(n);
  p.particle_type.resize(n);
  for (int i = 0; i < n; ++i) {
    const int g = p.global_id[i];
    p.state.inv_mass[i] = d.owned(i) ? w.state.inv_mass[g] : 0.0;  // ghosts: moved by their owners only
    p.particle_type[i] = w.particle_type[g];
  }
  p.state.t = s.t;
  p.state.step = s.step;
  // The owned molecules' bonded terms, in the whole system's order (so the constraint clusters,
  // and the effective dynamics' modes, come in the whole system's order too).
  const Topology& wt = w.topology;
  Topology& t = p.topology;
  t.bond_types = wt.bond_types, t.angle_types = wt.angle_types, t.dihedral_types = wt.dihedral_types;
  const auto mine = [&](int g) {
    const int i = d.local_index(g);
    return i >= 0 && d.owned(i);
  };
  for (const Bond& b : wt.bonds)
    if (mine(b.i)) t.bonds.push_back({d.local_index(b.i), d.local_index(b.j), b.type});
  for (const Angle& a : wt.angles)
    if (mine(a.i)) t.angles.push_back({d.local_index(a.i), d.local_index(a.j), d.local_index(a.k), a.type});
  for (const Dihedral& h : wt.dihedrals)
    if (mine(h.i))
      t.dihedrals.push_back({d.local_index(h.i), d.local_index(h.j), d.local_index(h.k), d.local_index(h.l), h.type});
  ThermostatSettings& th = p.integrator.thermostat;
  if (th.friction.size() > 0) {
    Eigen::VectorXd f(n);
    for (int i = 0; i < n; ++i) f[i] = w.integrator.thermostat.friction[p.global_id[i]];
    th.friction = f;
  }
  th.particle_id.assign(p.global_id.begin(), p.global_id.end());
  th.processes = &comm_;
  th.degrees_of_freedom = whole_dof_;
  read_force_terms(deck_, p);
  Decomposition* domains = domains_.get();
  p.forces->set_halo([domains](const Eigen::Matrix3Xd& a) { domains->halo(const_cast<Eigen::Matrix3Xd&>(a)); });
  std::vector<char> ghost(n);
  for (int i = 0; i < n; ++i) ghost[i] = !d.owned(i);
  p.forces->set_ghosts(ghost);
  part->integrator = make_integrator(p.integrator, *p.forces, p.state.inv_mass);
  if (std::vector<double> inv = part_invariants(); !inv.empty()) part->integrator->set_invariants(inv);
  part_ = std::move(part);
}

// The parts take over what the whole-system integrator carries (a restart's cached kick forces,
// or what the first sample left): each its particles' columns, rank 0 the sums.
void DomainIntegrator::start(const State& s) {
  Eigen::Matrix3Xd x, v;
  domains_->distribute(s, x, v);
  build_part(std::move(x), std::move(v), s);
  CarriedState c = whole_->carried_state();
  const std::vector<int>& ids = domains_->local_ids();
  for (Eigen::Matrix3Xd& column : c.columns) {
    Eigen::Matrix3Xd mine = Eigen::Matrix3Xd::Zero(3, domains_->num_local());
    for (int i : domains_->owned_particles()) mine.col(i) = column.col(ids[i]);
    column = std::move(mine);
  }
  if (!comm_.root()) std::fill(c.sums.begin(), c.sums.end(), 0.0);
  part_->integrator->restore_carried_state(std::move(c));
}

// The molecules move with what the part's integrator carries for their particles (cached kick
// forces, a Langevin force among them: they are not recomputed, so the run goes on as if
// nothing had moved).
void DomainIntegrator::rebuild() {
  const ScopedPhase phase(Phase::domain);
  State& l = part_->scene.state;
  CarriedState carried = part_->integrator->carried_state();
  std::vector<Eigen::Matrix3Xd*> columns;
  for (Eigen::Matrix3Xd& c : carried.columns) columns.push_back(&c);
  Eigen::Matrix3Xd x = std::move(l.x), v = std::move(l.v);
  domains_->redistribute(x, v, columns);
  build_part(std::move(x), std::move(v), l);
  part_->integrator->restore_carried_state(std::move(carried));
  last_displacement_ = 0.0;
}

void DomainIntegrator::step(State& s, double h) {
  if (!part_)
    start(s);
  else if (redistribute_)
    rebuild();
  redistribute_ = false;
  State& l = part_->scene.state;
  l.step = s.step;
  l.t = s.t;
  part_->integrator->step(l, h);
  // One reduction: the largest displacement since the ghosts were selected, and the first
  // particle (global index) with a non-finite position or velocity.
  double first_bad = -std::numeric_limits<double>::infinity();
  for (int i : domains_->owned_particles())
    if (!l.x.col(i).allFinite() || !l.v.col(i).allFinite()) {
      first_bad = -static_cast<double>(part_->scene.global_id[i]);
      break;
    }
  double reduced[2] = {domains_->max_displacement(l.x), first_bad};
  {
    const ScopedPhase phase(Phase::domain);
    comm_.max(reduced, 2);
  }
  if (std::isfinite(reduced[1])) {
    std::ostringstream m;
    m << "numerical failure: non-finite position or velocity of particle " << static_cast<long>(-reduced[1]);
    throw AgreedStop(m.str(), comm_.root());
  }
  // Redistribute before the next step if it may take a bead past margin/2: its displacement is
  // bounded by twice the last step's growth (a step's displacement changes slowly).
  const double d = reduced[0];
  const double growth = std::max(d - last_displacement_, 0.0);
  last_displacement_ = d;
  if (domains_->margin() > 0.0 && d + 2.0 * growth >= 0.5 * domains_->margin()) redistribute_ = true;
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

std::vector<double> DomainIntegrator::save_state() const {
  if (!part_) return whole_->save_state();
  // The whole system's state: the parts' columns by global index, their sums added, the flags
  // (alike on every rank) and the invariants as they are.
  CarriedState c = part_->integrator->carried_state();
  if (!c.sums.empty()) comm_.sum(c.sums.data(), static_cast<int>(c.sums.size()));
  std::vector<Eigen::Matrix3Xd> whole_columns;
  domains_->gather_columns(c.columns, whole_columns, whole_scene_.state.size());
  if (!comm_.root()) return {};
  c.columns = std::move(whole_columns);
  whole_->restore_carried_state(std::move(c));
  return whole_->save_state();
}

void DomainIntegrator::gather(State& whole) const {
  if (part_) domains_->gather(part_->scene.state.x, part_->scene.state.v, whole);
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
  const int owned = domains_->num_owned();
  double v[4] = {owned > 0 ? static_cast<double>(domains_->num_local() - owned) / owned : 0.0,
                 8.0 * static_cast<double>(domains_->halo_doubles()), static_cast<double>(domains_->halo_messages()),
                 static_cast<double>(domains_->migrated_molecules())};
  comm_.sum(v, 4);
  r.ghosts_per_owned = v[0] / r.ranks;
  r.halo_bytes_per_step = v[1];
  r.halo_messages_per_step = v[2];
  r.migrated_molecules = static_cast<long>(v[3]);
  r.redistributions = domains_->redistributions();
  return r;
}

}  // namespace stiffmd
