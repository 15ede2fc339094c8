// Decks: TOML (toml++) with variables and expressions in numeric fields (muparser),
// command-line overrides (`--set key=value`) and strict checking: every error is one line
// naming the file and line (or the --set that supplied the value), the dotted key and what
// was expected, and is thrown as InputError (exit 2).
//
//   [variables]                 # numbers or expressions over earlier-resolved variables
//   eps = 1e-3
//   [integrator]
//   h = "eps/100"               # any numeric field may be an expression string
#pragma once

#include <Eigen/Core>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace toml {
inline namespace v3 {
class node;
class table;
}  // namespace v3
}  // namespace toml

namespace stiffmd {

class Deck;

// Every number a deck gives (after its expression is evaluated) is 0 or lies in this window of
// magnitudes: far beyond any scene in reduced units, far inside the doubles, so that the products
// the force kernels form of a few of them (α²/ε², m g·x, r²) neither overflow nor underflow.
inline constexpr double kLargestDeckNumber = 1e100;
inline constexpr double kSmallestDeckNumber = 1e-100;

// A view of one TOML table that remembers which keys were read, so that finish() can
// reject the keys nobody asked for (typos, keys of another style).
class DeckTable {
 public:
  DeckTable(const Deck* deck, const toml::table* table, std::string path);

  bool has(std::string_view key) const;
  // Whether `key` holds an array (a key that takes one value or a list).
  bool is_array(std::string_view key) const;
  // Whether a key that is no longer read (and is not listed among this table's keys) was given.
  bool has_retired(std::string_view key) const;
  // Whether the key is given, without counting it among the keys this table takes (a look ahead
  // before the table's reader runs: the order in which [forces] are read).
  bool gives(std::string_view key) const { return has_retired(key); }

  double number(std::string_view key);
  double number(std::string_view key, double fallback);
  std::optional<double> maybe_number(std::string_view key);
  long integer(std::string_view key);
  long integer(std::string_view key, long fallback);
  std::optional<long> maybe_integer(std::string_view key);
  std::string string(std::string_view key);
  std::string string(std::string_view key, std::string fallback);
  // A name (a particle, bond, angle or dihedral type, a level, a style): a non-empty string. An
  // empty name would select nothing and let a term apply to no particle without a word.
  std::string name(std::string_view key);
  std::string name(std::string_view key, std::string fallback);
  bool boolean(std::string_view key, bool fallback);
  Eigen::Vector3d vector3(std::string_view key);
  Eigen::Vector3d vector3(std::string_view key, const Eigen::Vector3d& fallback);
  // Three booleans, or one boolean meaning all three axes.
  Eigen::Vector3i bool3(std::string_view key, bool fallback);
  // A list of integers (e.g. a bond's two particle indices).
  std::vector<long> integers(std::string_view key);
  std::vector<std::string> strings(std::string_view key);
  // A list of numbers or expressions; empty when absent.
  std::vector<double> numbers(std::string_view key);
  // A table of string values, e.g. atom_types = { "1" = "bead" }; empty when absent.
  std::vector<std::pair<std::string, std::string>> string_map(std::string_view key);
  // A table of lists of values, e.g. vary = { "thermostat.seed" = [1, 2] }, its nested tables
  // flattened to dotted keys ([t.vary.thermostat] seed = [1, 2] is the same): each list's
  // elements as TOML text (what --set key=text reads back as the same value), and where the list
  // is ("file:line"); empty when absent. Every list must be non-empty.
  struct ValueList {
    std::string key, where;
    std::vector<std::string> values;
  };
  std::vector<ValueList> value_lists(std::string_view key);

  std::optional<DeckTable> table(std::string_view key);
  // Every entry of this table must itself be a table: [types.A], [types.B], …
  std::vector<std::pair<std::string, DeckTable>> named_tables();
  // An array of tables ([[particles]]); empty when the key is absent.
  std::vector<DeckTable> array_of_tables(std::string_view key);

  // Errors at a key (its file:line, or the --set that gave it) or at this table. `related`: the
  // dotted key paths of other values the condition used (integrator.h for a t_end that is no
  // whole number of steps): a --set among them is named too, since it may be what broke it.
  [[noreturn]] void fail(std::string_view key, const std::string& what,
                         const std::vector<std::string>& related = {}) const;
  [[noreturn]] void fail_here(const std::string& what, const std::vector<std::string>& related = {}) const;
  // "file:line: path" of this table, for errors raised after reading (e.g. by [prepare]).
  std::string where() const;
  // "file:line: path.key" (or "--set path.key: path.key") of a key, with `related` as in fail():
  // for warnings and errors raised after reading, at the key rather than at its table.
  std::string where(std::string_view key, const std::vector<std::string>& related = {}) const;
  // Check that a number read from `key` satisfies a condition.
  void require(bool ok, std::string_view key, const std::string& what) const {
    if (!ok) fail(key, what);
  }

  // Rejects every key that was never asked for, listing the ones this table accepts (and the one
  // a misspelled key most likely means).
  void finish() const;
  // A required key (or table) `key` is absent: fails at a key of this table that looks like a
  // misspelling of it ("did you mean"), else at the table, with `what`.
  [[noreturn]] void missing(std::string_view key, const std::string& what) const;

  const std::string& path() const { return path_; }
  std::string key_path(std::string_view key) const;
  // A key path as messages name it (Deck::shown_path).
  std::string shown_key(const std::string& key_path) const;

 private:
  const toml::node* get(std::string_view key);
  double to_number(const toml::node& n, const std::string& key_path) const;

  const Deck* deck_;
  const toml::table* table_;
  std::string path_;
  std::set<std::string, std::less<>> used_;
  mutable std::set<std::string, std::less<>> known_;  // every key asked for, present or not
};

class Deck {
 public:
  // Parses the file and applies the overrides ("a.b.c=value"; the value is read as TOML, or
  // as a string when it is not valid TOML: --set integrator.method=impulse works unquoted).
  Deck(std::string path, const std::vector<std::string>& overrides);
  // A deck given as TOML text (the Python module): `name` stands for the file in error
  // messages, and relative paths ([import]) are taken from the working directory.
  struct Text {
    std::string name, toml;
  };
  Deck(const Text& deck, const std::vector<std::string>& overrides);
  // One element of an array of tables merged over the rest of the deck (a [[stage]] of a staged
  // protocol, engine/scene/stage_deck.hpp): the base deck's text and --set read again, then the
  // element `element` of the root array `array` taken out of it and merged over the root key by
  // key — each of its tables into the root's table of that name (a value replaces the base's, a
  // table merges into the base's table), its plain values named in `moved` into the root table
  // `moved_into` (which they replace whole; the element's other plain values are left out) — and
  // `array` removed. Every value keeps its file:line; messages name a merged value by its path in
  // the element ("stage[1].integrator.h", not "integrator.h"), and a --set of it as given.
  struct Merge {
    std::string array;
    std::size_t element = 0;
    std::vector<std::string> moved;
    std::string moved_into;
  };
  Deck(const Deck& base, const Merge& merge);
  ~Deck();
  Deck(const Deck&) = delete;
  Deck& operator=(const Deck&) = delete;

  DeckTable root() const;
  const std::string& path() const { return path_; }
  const std::map<std::string, double>& variables() const { return variables_; }

  // Where a value came from, for messages: "--set a.b" when it (or a table above it) was given
  // on the command line, else "file:line" — followed by " (with --set x.y, ...)" for the --set
  // values it was formed from: keys inside it (a table), variables its expression refers to
  // (directly or through other variables), and the `related` key paths (other values the
  // message's condition used). An error caused by a --set then names the --set, wherever the
  // check that found it stands.
  std::string location(const toml::node* n, const std::string& key_path,
                       const std::vector<std::string>& related = {}) const;
  // The --set key that gave the value at this key path, or at a table above it; empty if none.
  std::string override_of(const std::string& key_path) const;
  // A key path as the deck file spells it: a value a Merge moved is named where it was written
  // ("run.steps" -> "stage[1].steps"); every other path as it is.
  std::string shown_path(const std::string& key_path) const;
  // Records that the node's string was evaluated as an expression (its variables are sources).
  void mark_expression(const toml::node* n) const { expressions_.insert(n); }
  // Evaluates a muparser expression over the deck's variables; throws InputError on failure.
  double evaluate(const std::string& expr, const std::string& where) const;

 private:
  void parse(const std::string& text, const std::vector<std::string>& overrides);
  void apply_override(const std::string& assignment);
  void resolve_variables();
  // The variable names an expression refers to, defined or not (throws InputError on a syntax error).
  std::set<std::string> referenced_names(const std::string& expr, const std::string& where) const;
  // The --set keys among the variables an expression refers to, through other variables too.
  void add_variable_sources(const std::string& expr, std::set<std::string>& sources,
                            std::set<std::string>& visited) const;

  void merge_element(const Merge& merge);

  std::string path_;
  std::string text_;                    // the TOML text, read again for a Merge
  std::vector<std::string> overrides_;  // the --set assignments, as given
  std::unique_ptr<toml::table> table_;
  std::set<std::string> overridden_;
  // A Merge's renames: a --set key path as the merged deck has it -> as given; a merged value's
  // key path -> where the deck file has it.
  std::map<std::string, std::string> override_shown_;
  std::vector<std::pair<std::string, std::string>> shown_paths_;
  std::map<std::string, double> variables_;
  mutable std::set<const toml::node*> expressions_;  // string values evaluated as expressions
};

// The name among `known` that `typed` most likely misspells ("did you mean"), or "" if none
// looks like it: at most one edit in five characters (another case counts), and for names
// shorter than four characters another case only — one edit of a key such as r0 or K is often
// another style's key — or one edit when `known` holds every name there is (`every_name`: a
// command's subcommands).
std::string nearest_name(std::string_view typed, const std::vector<std::string>& known, bool every_name = false);

}  // namespace stiffmd
