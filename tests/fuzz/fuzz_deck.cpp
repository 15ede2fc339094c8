// libFuzzer target: the bytes as a TOML deck, through Deck and load_scene — a staged deck through
// every stage's deck and scene (load_protocol), then on with the first stage's — and what `stiffmd
// check` does next: describe the scene, write its initial state as LAMMPS data and read that
// back). stiffmd::InputError is the expected outcome of a bad deck; any other exception, a crash,
// a hang or a sanitizer report is a finding.
//
// Leading lines "#set KEY=VALUE" (TOML comments, so the deck still parses) become --set
// overrides, so that the override path is fuzzed too.
//
//   build-fuzz/fuzz_deck -dict=tests/fuzz/deck.dict CORPUS_DIR   (see tools/fuzz.sh)
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/run/run.hpp"
#include "engine/run/stages.hpp"
#include "engine/scene/scene.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace stiffmd;
  static const fuzz::ScratchFile deck_file("deck.toml"), data_file("initial.data");
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> overrides;
  for (std::size_t pos = 0; text.substr(pos, 5) == "#set ";) {
    const std::size_t end = std::min(text.find('\n', pos), text.size());
    overrides.emplace_back(text.substr(pos + 5, end - pos - 5));
    pos = end + 1;
    if (pos >= text.size()) break;
  }
  deck_file.write(data, size);

  Scene scene;
  try {
    const Deck deck(deck_file.path, overrides);
    DeckTable root = deck.root();
    std::vector<StageSpec> stages = read_stages(root);
    if (stages.empty()) {
      scene = load_scene(deck);
    } else {  // a staged protocol: every stage's deck and scene, as `stiffmd check` loads them
      Protocol protocol = load_protocol(deck, std::move(stages), 1);
      scene = std::move(*protocol.scene);
    }
    std::ostringstream log;
    prepare_scene(scene, log);
  } catch (const InputError&) {
    return 0;  // the expected outcome of a bad deck
  } catch (const std::exception& e) {
    fuzz::finding("load_scene threw something other than InputError", &e);
  }
  try {
    (void)describe(scene);
    (void)scene.num_steps();
    (void)output_files(scene);
  } catch (const std::exception& e) {
    fuzz::finding("describing a loaded scene threw", &e);
  }
  // `stiffmd check --write-data`: a scene that loaded must be writable, and readable back.
  try {
    write_scene_lammps_data(scene, data_file.path, "fuzz");
  } catch (const std::exception& e) {
    fuzz::finding("write_scene_lammps_data refused a loaded scene", &e);
  }
  try {
    const ImportedSystem back = read_lammps_data(data_file.path);
    if (back.x.cols() != scene.state.x.cols()) fuzz::finding("the written initial state reads back with another size");
  } catch (const std::exception& e) {
    fuzz::finding("the written initial state does not read back", &e);
  }
  return 0;
}
