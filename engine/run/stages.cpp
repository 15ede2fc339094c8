#include "engine/run/stages.hpp"

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include "core/errors.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/run/signals.hpp"

namespace stiffmd {
namespace fs = std::filesystem;

namespace {

const std::string kContinue = ": continue it with the deck it was written with";

// An InputError of stage `stage` says which stage it is of.
template <class Work>
auto in_stage(const StageIdentity& stage, Work&& work) {
  try {
    return work();
  } catch (const InputError& e) {
    const std::string what = e.what(), label = stage_label(stage) + ": ";
    throw InputError(what.rfind(label, 0) == 0 ? what : label + what);
  }
}

// The stage's [minimize] on the state it starts from (prepare_scene without [prepare], which is
// the protocol's first state's: a later stage takes its state from the previous one).
void minimize_at_start(Scene& sc, std::ostream& log, std::ostream* progress) {
  if (!sc.minimize.requested) return;
  sc.prepare.requested = false;
  in_stage(sc.stage, [&] { prepare_scene(sc, log, progress); });
}

// "warning: stage 2 (equilibrate): file:line: …": the stage after the note's kind.
std::string stage_note(const StageIdentity& stage, const std::string& note) {
  for (const char* kind : {"warning: ", "note: "})
    if (note.rfind(kind, 0) == 0) return kind + stage_label(stage) + ": " + note.substr(std::string(kind).size());
  return stage_label(stage) + ": " + note;
}

// Rank 0's state (a decomposed run's whole state is gathered there at its end) on every rank,
// where the next stage's setup starts from it alike. Collective.
void share_state(Scene& sc, const Communicator* processes) {
  if (!processes || processes->size() == 1) return;
  State& s = sc.state;
  processes->broadcast(s.x.data(), static_cast<int>(s.x.size()));
  processes->broadcast(s.v.data(), static_cast<int>(s.v.size()));
  Box box = sc.forces->box();  // the box now (a barostat moves it, alike on every rank)
  processes->broadcast(box.origin.data(), 3);
  processes->broadcast(box.lengths.data(), 3);
  sc.forces->set_box(box);
}

std::string json_string(const std::string& s) {
  std::ostringstream o;
  o << '"';
  for (const char c : s) {
    if (c == '"' || c == '\\')
      o << '\\' << c;
    else if (static_cast<unsigned char>(c) < 0x20)
      o << "\\u00"
        << "0123456789abcdef"[(c >> 4) & 0xf] << "0123456789abcdef"[c & 0xf];
    else
      o << c;
  }
  o << '"';
  return o.str();
}

// A top-level number of a summary.json as summary_json writes it ("\n  \"key\": value"), as
// written; "null" when absent.
std::string summary_field(const std::string& json, const std::string& key) {
  const std::string k = "\n  \"" + key + "\": ";
  const auto at = json.find(k);
  if (at == std::string::npos) return "null";
  const auto from = at + k.size();
  return json.substr(from, json.find_first_of(",\n", from) - from);
}

// OUT/protocol.json: every stage's row from its summary.json (those of the stages run before a
// restart included), written whole or not at all.
std::string write_protocol_json(const Protocol& p, const std::string& out_dir) {
  std::ostringstream o;
  o << "{\n  \"deck\": " << json_string(p.deck_path)
    << ",\n  \"restarted_from\": " << (p.restart.empty() ? "null" : json_string(p.restart)) << ",\n  \"stages\": [";
  for (int k = 0; k < p.count(); ++k) {
    const StageIdentity& stage = p.stages[k].identity;
    const fs::path dir = fs::path(out_dir) / stage_directory(stage);
    std::ifstream in(dir / "summary.json");
    std::stringstream text;
    text << in.rdbuf();
    const std::string json = in ? text.str() : "";
    o << (k ? ",\n" : "\n") << "    {\"number\": " << stage.number << ", \"name\": " << json_string(stage.name)
      << ", \"directory\": " << json_string(dir.string())
      << ", \"summary\": " << (json.empty() ? "null" : json_string((dir / "summary.json").string()));
    for (const char* key : {"method", "h", "steps", "t_end", "final_energy", "wall_seconds"})
      o << ", \"" << key << "\": " << summary_field(json, key);
    o << "}";
  }
  o << "\n  ]\n}\n";
  const fs::path path = fs::path(out_dir) / "protocol.json", tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp);
    out << o.str();
    if (!out) throw InputError(tmp.string() + ": write failed");
  }
  fs::rename(tmp, path);
  return path.string();
}

}  // namespace

void pass_state(const Scene& from, Scene& to) {
  if (from.state.size() != to.state.size() || from.state.inv_mass != to.state.inv_mass)
    throw std::logic_error("pass_state: the stages are not of one scene");
  to.state.x = from.state.x;
  to.state.v = from.state.v;
  to.state.step = 0;  // each stage counts its steps and time from 0
  to.state.t = 0.0;
  // The box as the previous stage left it (a barostat moves it): the force field's, which every
  // evaluation and the neighbour lists read. The scene's own box stays the deck's, which the scene
  // fingerprint holds (a stage restarted from its checkpoint takes the box from there).
  to.forces->set_box(from.forces->box());
}

Protocol load_protocol(const Deck& base, std::vector<StageSpec> stages, int ranks) {
  Protocol p;
  p.deck_path = base.path();
  p.stages = std::move(stages);
  std::uint64_t first = 0;
  std::set<std::string> said;
  for (const StageSpec& spec : p.stages) {
    p.decks.push_back(stage_deck(base, spec));
    Scene sc = load_stage_scene(*p.decks.back(), spec);
    if (ranks > 1)
      in_stage(spec.identity, [&] {
        check_parallel_grid(sc, ranks);
        check_parallel_outputs(sc, ranks);
      });
    // What a stage may set cannot change the scene (read_stages): the state passed on fits.
    const std::uint64_t fingerprint = scene_fingerprint(sc);
    if (spec.identity.number == 1) first = fingerprint;
    if (fingerprint != first)
      throw InputError(stage_label(spec.identity) + ": " + spec.where +
                       ": the stage's scene differs from stage 1's (particle types, topology, box or force "
                       "terms): a stage changes how the scene is run, not the scene");
    for (const std::string& note : sc.notes)
      if (said.insert(note).second) p.notes.push_back(stage_note(spec.identity, note));
    if (spec.identity.number == 1) p.scene.emplace(std::move(sc));
  }
  return p;
}

void start_protocol(Protocol& p, std::ostream& log, std::ostream* progress) {
  in_stage(p.scene->stage, [&] { prepare_scene(*p.scene, log, progress); });
}

void resume_protocol(Protocol& p, const std::string& path, std::ostream& log, std::ostream* progress) {
  const Checkpoint head = read_checkpoint(path);  // format and checksum first
  if (head.stage == 0)
    throw InputError(path + ": checkpoint of a run without stages, and the deck is a protocol of " +
                     std::to_string(p.count()) + " stages" + kContinue);
  const StageIdentity written{head.stage, 0, head.stage_name};
  if (head.stage > p.count())
    throw InputError(path + ": checkpoint of " + stage_label(written) + ", and the deck has " +
                     std::to_string(p.count()) + (p.count() == 1 ? " stage" : " stages") + kContinue);
  const std::size_t k = static_cast<std::size_t>(head.stage - 1);
  const StageSpec& spec = p.stages[k];
  if (spec.identity.name != head.stage_name)
    throw InputError(path + ": checkpoint of " + stage_label(written) + ", and the deck's stage " +
                     std::to_string(head.stage) + " is named \"" + spec.identity.name + "\"" + kContinue);
  Scene sc = k == 0 ? std::move(*p.scene) : load_stage_scene(*p.decks[k], spec);
  p.scene.reset();
  const Checkpoint c = read_checkpoint_of(sc, path);
  if (!checkpoint_at_end(sc, c)) {  // inside the stage: the Run continues it
    p.checkpoint = read_checkpoint_for(sc, path);
    p.start = k;
    p.restart = path;
    p.scene.emplace(std::move(sc));
    return;
  }
  // The stage's final checkpoint: the next stage starts from its state.
  if (k + 1 == p.stages.size())
    throw InputError(path + ": checkpoint at the end of " + stage_label(spec.identity) +
                     ", the protocol's last stage: nothing is left to run (a longer stage: --set stage." +
                     std::to_string(spec.index) + ".steps=... or t_end=...)");
  sc.state = c.state;
  if (c.has_box) {
    Box box = sc.forces->box();
    box.origin = c.box.origin, box.lengths = c.box.lengths;
    sc.forces->set_box(box);
  }
  const StageSpec& next = p.stages[k + 1];
  Scene to = load_stage_scene(*p.decks[k + 1], next);
  pass_state(sc, to);
  log << "restart from " << path << ": " << stage_label(spec.identity) << " ended at step " << c.state.step << "; "
      << stage_label(next.identity) << " starts from its state\n";
  minimize_at_start(to, log, progress);
  p.start = k + 1;
  p.restart = path;
  p.scene.emplace(std::move(to));
}

std::string check_protocol(Protocol& p, std::ostream& log) {
  Scene& first = *p.scene;
  in_stage(first.stage, [&] { prepare_scene(first, log); });
  std::ostringstream d;
  d << describe_scene(first) << "stages:      " << p.count() << "\n";
  for (std::size_t k = 0; k < p.stages.size(); ++k) {
    const StageSpec& spec = p.stages[k];
    std::optional<Scene> later;
    if (k > 0) {
      later.emplace(load_stage_scene(*p.decks[k], spec));
      pass_state(first, *later);
    }
    Scene& sc = later ? *later : first;
    in_stage(spec.identity, [&] { check_run(sc, log); });
    d << "stage " << spec.identity.number << "/" << p.count() << " " << spec.identity.name << ":\n";
    std::istringstream lines(describe_settings(sc));
    for (std::string line; std::getline(lines, line);) d << "  " << line << "\n";
    if (sc.minimize.requested)
      d << "  minimize:    " << style_name(sc.minimize.style) << " at the stage's start, ftol " << sc.minimize.ftol
        << ", etol " << sc.minimize.etol << ", maxiter " << sc.minimize.maxiter << "\n";
  }
  return d.str();
}

ProtocolOutcome run_protocol(Protocol& p, const RunOptions& options, std::ostream& log, std::FILE* stages_out) {
  ProtocolOutcome out;
  const Communicator* processes = options.processes && options.processes->size() > 1 ? options.processes : nullptr;
  const bool root = !processes || processes->root();
  const bool files = !options.out_dir.empty();
  if (root && files) {  // a protocol.json describes a finished protocol only
    std::error_code ec;
    fs::remove(fs::path(options.out_dir) / "protocol.json", ec);
  }
  std::optional<Scene> current(std::move(*p.scene)), previous;
  p.scene.reset();
  std::string last_checkpoint;
  for (std::size_t k = p.start; k < p.stages.size(); ++k) {
    const StageSpec& spec = p.stages[k];
    if (k > p.start) {
      // A SIGINT/SIGTERM since the last stage's end: stop before this one, at that stage's final
      // checkpoint (rank 0's signal decides, as within a run).
      if (options.handle_signals) {
        std::int64_t sig = stop_requested();
        if (processes) processes->broadcast(&sig, 1);
        if (sig != 0) {
          out.stopped_by_signal = static_cast<int>(sig);
          out.checkpoint = last_checkpoint;
          out.where = "after " + stage_label(p.stages[k - 1].identity);
          return out;
        }
      }
      share_state(*previous, processes);
      agree(processes, [&] {
        current.emplace(load_stage_scene(*p.decks[k], spec));
        pass_state(*previous, *current);
        minimize_at_start(*current, log, options.progress ? &log : nullptr);
      });
      previous.reset();
    }
    const std::string dir = files ? (fs::path(options.out_dir) / stage_directory(spec.identity)).string() : "";
    if (stages_out) {
      std::fprintf(stages_out, "stage %d/%d %s -> %s\n", spec.identity.number, p.count(), spec.identity.name.c_str(),
                   dir.c_str());
      std::fflush(stages_out);
    }
    RunOptions stage_options = options;
    stage_options.out_dir = dir;
    const bool resuming = k == p.start && p.checkpoint;
    stage_options.restart = resuming ? p.restart : "";
    stage_options.checkpoint = resuming ? &*p.checkpoint : nullptr;
    out.summaries.push_back(run_simulation(*current, stage_options, log));
    const RunSummary& s = out.summaries.back();
    if (s.stopped_by_signal) {
      out.stopped_by_signal = s.stopped_by_signal;
      out.checkpoint = s.checkpoint;
      out.where = "in " + stage_label(spec.identity);
      return out;
    }
    last_checkpoint = s.checkpoint;
    if (stages_out) {
      std::fputs(format_summary(s).c_str(), stages_out);
      std::fflush(stages_out);
    }
    previous = std::move(current);
    current.reset();
  }
  if (root && files) out.protocol_json = write_protocol_json(p, options.out_dir);
  return out;
}

}  // namespace stiffmd
