#include "engine/deck/deck.hpp"

#include <muParser.h>

#include <toml++/toml.h>
#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

#include "core/errors.hpp"
#include "core/format.hpp"

namespace stiffmd {
namespace {

std::string type_word(const toml::node& n) {
  switch (n.type()) {
    case toml::node_type::table:
      return "a table";
    case toml::node_type::array:
      return "an array";
    case toml::node_type::string:
      return "a string";
    case toml::node_type::integer:
      return "an integer";
    case toml::node_type::floating_point:
      return "a number";
    case toml::node_type::boolean:
      return "a boolean";
    default:
      return "a date/time";
  }
}

std::string shown(const toml::node& n) {
  std::ostringstream s;
  if (auto v = n.value<std::string>())
    s << '"' << *v << '"';
  else if (n.is_table())
    s << "a table";
  else if (n.is_array())
    s << "an array";
  else
    n.visit([&](const auto& x) { s << x; });
  return s.str();
}

// A TOML number as a double. toml++ gives no value<double>() for an integer that has no exact
// double (beyond 2^53): convert it ourselves, rounding, rather than dereference an empty optional.
double as_double(const toml::node& n) {
  if (n.is_integer()) return static_cast<double>(*n.value<int64_t>());
  return *n.value<double>();
}

// Every string and every key of the deck (and of --set values): toml++ accepts "\u0000", which
// would cut a path or a name short where it reaches the C library (open a shorter file name) and
// print as nothing in messages. Throws InputError at the first one.
void refuse_nul(const Deck& deck, const toml::node& n, const std::string& kp) {
  const auto shown_key = [](std::string_view k) {
    std::string out;
    for (char c : k) out += c == '\0' ? std::string("\\u0000") : std::string(1, c);
    return out;
  };
  if (const auto* t = n.as_table()) {
    for (const auto& [k, v] : *t) {
      const std::string child = kp.empty() ? shown_key(k.str()) : kp + "." + shown_key(k.str());
      if (k.str().find('\0') != std::string_view::npos)
        throw InputError(deck.location(&v, child) + ": " + child +
                         ": the key contains a NUL character (\\u0000); expected a name without one");
      refuse_nul(deck, v, child);
    }
  } else if (const auto* a = n.as_array()) {
    for (size_t k = 0; k < a->size(); ++k) refuse_nul(deck, *a->get(k), kp + "[" + std::to_string(k) + "]");
  } else if (const auto v = n.value<std::string>(); v && v->find('\0') != std::string::npos) {
    throw InputError(deck.location(&n, kp) + ": " + kp +
                     ": the string contains a NUL character (\\u0000); expected text without one");
  }
}

// Array elements are "particles[1].position" in key paths but "particles.1.position" in overrides.
std::string dotted_path(const std::string& key_path) {
  std::string dotted;
  for (const char c : key_path)
    if (c == '[')
      dotted += '.';
    else if (c != ']')
      dotted += c;
  return dotted;
}

bool valid_identifier(const std::string& s) {
  if (s.empty() || std::isdigit(static_cast<unsigned char>(s[0]))) return false;
  for (char c : s)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_') return false;
  return true;
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Deck

Deck::Deck(std::string path, const std::vector<std::string>& overrides) : path_(std::move(path)) {
  std::error_code ec;
  if (std::filesystem::is_directory(path_, ec))
    throw InputError(path_ + ": is a directory, expected a deck file (TOML)");
  std::ifstream in(path_, std::ios::binary);
  if (!in) throw InputError(path_ + ": cannot open deck file");
  // Read at most kMaxDeckBytes: a deck may come through a pipe (process substitution), but
  // /dev/zero or an endless pipe must not be read forever.
  constexpr std::size_t kMaxDeckBytes = 64 << 20;
  std::string text;
  char chunk[1 << 16];
  while (in.read(chunk, sizeof chunk) || in.gcount() > 0) {
    text.append(chunk, static_cast<std::size_t>(in.gcount()));
    if (text.size() > kMaxDeckBytes)
      throw InputError(path_ + ": larger than " + std::to_string(kMaxDeckBytes >> 20) +
                       " MiB; expected a deck file (TOML)");
  }
  if (in.bad()) throw InputError(path_ + ": cannot read deck file");
  parse(text, overrides);
}

Deck::Deck(const Text& deck, const std::vector<std::string>& overrides) : path_(deck.name) {
  parse(deck.toml, overrides);
}

void Deck::parse(const std::string& text, const std::vector<std::string>& overrides) {
  text_ = text;
  overrides_ = overrides;
  try {
    table_ = std::make_unique<toml::table>(toml::parse(text, path_));
  } catch (const toml::parse_error& e) {
    throw InputError(path_ + ":" + std::to_string(e.source().begin.line) +
                     ": TOML syntax error: " + std::string(e.description()));
  }
  for (const std::string& o : overrides) apply_override(o);
  refuse_nul(*this, *table_, "");
  resolve_variables();
}

Deck::Deck(const Deck& base, const Merge& merge) : path_(base.path_), text_(base.text_), overrides_(base.overrides_) {
  // Parsed again rather than copied: toml++ copies a node without its source region, and every
  // message names the file:line of its value.
  table_ = std::make_unique<toml::table>(toml::parse(text_, path_));
  for (const std::string& o : overrides_) apply_override(o);
  merge_element(merge);
  refuse_nul(*this, *table_, "");
  resolve_variables();
}

namespace {

// `src`'s entries moved into `dst` key by key: a table into a table of the same name, anything
// else replacing dst's value. Moving (not copying) keeps each node's file:line. `replaced` gets
// the key path of every value put into dst whole.
void merge_into(toml::table& dst, toml::table& src, const std::string& path, std::vector<std::string>& replaced) {
  std::vector<std::string> keys;
  for (const auto& [k, v] : src) keys.emplace_back(k.str());
  for (const std::string& k : keys) {
    toml::node& v = *src.get(k);
    const std::string kp = path.empty() ? k : path + "." + k;
    toml::node* old = dst.get(k);
    if (v.is_table() && old && old->is_table()) {
      merge_into(*old->as_table(), *v.as_table(), kp, replaced);
      continue;
    }
    v.visit([&](auto& value) { dst.insert_or_assign(k, std::move(value)); });
    replaced.push_back(kp);
  }
}

bool under(const std::string& kp, const std::string& prefix) {
  return kp == prefix || kp.rfind(prefix + ".", 0) == 0 || kp.rfind(prefix + "[", 0) == 0;
}

}  // namespace

void Deck::merge_element(const Merge& m) {
  toml::array* array = table_->get_as<toml::array>(m.array);
  if (!array || m.element >= array->size() || !array->get(m.element)->is_table())
    throw std::invalid_argument("Deck merge: no table " + m.array + "[" + std::to_string(m.element) + "]");
  toml::table element = std::move(*array->get(m.element)->as_table());
  table_->erase(m.array);
  const std::string shown = m.array + "[" + std::to_string(m.element) + "]";
  const std::string given = m.array + "." + std::to_string(m.element);
  // The element's --set keys, as the merged deck has them; the other elements' are gone.
  std::map<std::string, std::string> moved_overrides;
  for (auto it = overridden_.begin(); it != overridden_.end();) {
    if (!under(*it, m.array)) {
      ++it;
      continue;
    }
    if (it->rfind(given + ".", 0) == 0) {
      std::string rest = it->substr(given.size() + 1);
      const std::string first = rest.substr(0, rest.find('.'));
      if (std::find(m.moved.begin(), m.moved.end(), first) != m.moved.end()) rest = m.moved_into + "." + rest;
      moved_overrides[rest] = *it;
    }
    it = overridden_.erase(it);
  }
  std::vector<std::string> replaced;
  std::vector<std::string> keys;
  for (const auto& [k, v] : element) keys.emplace_back(k.str());
  bool moves = false;
  for (const std::string& k : keys) {
    toml::node& v = *element.get(k);
    if (std::find(m.moved.begin(), m.moved.end(), k) != m.moved.end()) {
      moves = true;
      continue;
    }
    if (v.is_table()) {
      toml::node* dst = table_->get(k);
      if (dst && dst->is_table()) {
        merge_into(*dst->as_table(), *v.as_table(), k, replaced);
      } else {  // the element's table whole, with its file:line
        v.visit([&](auto& value) { table_->insert_or_assign(k, std::move(value)); });
        replaced.push_back(k);
      }
    }
    element.erase(k);
  }
  // The moved values stay in the element's own table (so that the table keeps its file:line, the
  // element's header), which replaces `moved_into`.
  if (moves) {
    table_->insert_or_assign(m.moved_into, std::move(element));
    replaced.push_back(m.moved_into);
    shown_paths_.emplace_back(m.moved_into, shown);
  }
  for (const std::string& kp : replaced) {
    // A base value the element replaced is no longer the --set's that set it.
    for (auto it = overridden_.begin(); it != overridden_.end();) it = under(*it, kp) ? overridden_.erase(it) : ++it;
    if (kp != m.moved_into) shown_paths_.emplace_back(kp, shown + "." + kp);
  }
  for (const auto& [kp, o] : moved_overrides) {
    overridden_.insert(kp);
    override_shown_[kp] = o;
  }
}

std::string Deck::shown_path(const std::string& key_path) const {
  for (const auto& [merged, written] : shown_paths_)
    if (under(key_path, merged)) return written + key_path.substr(merged.size());
  return key_path;
}

Deck::~Deck() = default;

DeckTable Deck::root() const {
  return DeckTable(this, table_.get(), "");
}

std::string Deck::override_of(const std::string& key_path) const {
  const std::string dotted = dotted_path(key_path);
  for (const std::string& o : overridden_)
    for (const std::string& kp : {key_path, dotted})
      if (kp == o || kp.rfind(o + ".", 0) == 0 || kp.rfind(o + "[", 0) == 0) return o;
  return "";
}

std::string Deck::location(const toml::node* n, const std::string& key_path,
                           const std::vector<std::string>& related) const {
  const auto given = [&](const std::string& o) {
    const auto it = override_shown_.find(o);
    return it == override_shown_.end() ? o : it->second;
  };
  if (const std::string o = override_of(key_path); !o.empty()) return "--set " + given(o);
  std::string where = path_;
  if (n && n->source().begin.line > 0) where += ":" + std::to_string(n->source().begin.line);
  std::set<std::string> sources;
  // A table holding values given with --set (not the root: its errors are about the whole deck,
  // and every --set lies inside it).
  const auto inside = [&](const std::string& kp) {
    const std::string dotted = dotted_path(kp);
    if (dotted.empty()) return;
    for (const std::string& o : overridden_)
      if (o.rfind(dotted + ".", 0) == 0) sources.insert(o);
  };
  inside(key_path);
  const bool variables_set = std::any_of(overridden_.begin(), overridden_.end(), [](const std::string& o) {
    return o == "variables" || o.rfind("variables.", 0) == 0;
  });
  if (n && variables_set && expressions_.count(n)) {
    std::set<std::string> visited;
    add_variable_sources(*n->value<std::string>(), sources, visited);
  }
  for (const std::string& r : related) {
    if (const std::string o = override_of(r); !o.empty()) sources.insert(o);
    inside(r);
  }
  if (sources.empty()) return where;
  where += " (with";
  for (auto it = sources.begin(); it != sources.end(); ++it)
    where += (it == sources.begin() ? " --set " : ", --set ") + given(*it);
  return where + ")";
}

void Deck::add_variable_sources(const std::string& expr, std::set<std::string>& sources,
                                std::set<std::string>& visited) const {
  std::set<std::string> names;
  try {
    names = referenced_names(expr, "");
  } catch (const InputError&) {
    return;  // a syntax error is reported as such where the expression is evaluated
  }
  const toml::table* vars = table_->get("variables") ? table_->get("variables")->as_table() : nullptr;
  for (const std::string& name : names) {
    if (!variables_.count(name) && !(vars && vars->contains(name))) continue;  // not a variable
    if (!visited.insert(name).second) continue;
    if (const std::string o = override_of("variables." + name); !o.empty()) {
      sources.insert(o);
    } else if (const toml::node* v = vars ? vars->get(name) : nullptr; v && v->is_string()) {
      add_variable_sources(*v->value<std::string>(), sources, visited);
    }
  }
}

void Deck::apply_override(const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw InputError("--set " + assignment + ": expected key=value (e.g. --set integrator.h=0.01)");
  const std::string key = assignment.substr(0, eq);
  const std::string text = assignment.substr(eq + 1);

  // The value as TOML if it parses, else as a bare string.
  toml::table parsed;
  try {
    parsed = toml::parse("v = " + text);
  } catch (const toml::parse_error&) {
    parsed = toml::table{};
    parsed.insert("v", text);
  }
  toml::node* value = parsed.get("v");

  std::vector<std::string> parts;
  std::stringstream ks(key);
  for (std::string part; std::getline(ks, part, '.');) {
    if (part.empty()) throw InputError("--set " + assignment + ": empty key segment in '" + key + "'");
    parts.push_back(part);
  }
  toml::node* cur = table_.get();
  std::string sofar;
  for (size_t k = 0; k < parts.size(); ++k) {
    const std::string& p = parts[k];
    const bool last = k + 1 == parts.size();
    sofar += (sofar.empty() ? "" : ".") + p;
    if (auto* t = cur->as_table()) {
      if (last) {
        value->visit([&](auto& v) { t->insert_or_assign(p, v); });
      } else {
        if (!t->contains(p)) t->insert(p, toml::table{});
        cur = t->get(p);
      }
    } else if (auto* a = cur->as_array()) {
      char* end = nullptr;
      const long idx = std::strtol(p.c_str(), &end, 10);
      if (*end != '\0' || idx < 0 || idx >= static_cast<long>(a->size()))
        throw InputError("--set " + assignment + ": '" + sofar + "' is not an element of the array (0.." +
                         std::to_string(a->size()) + ")");
      if (last)
        value->visit([&](auto& v) { a->replace(a->cbegin() + idx, v); });
      else
        cur = a->get(static_cast<size_t>(idx));
    } else {
      throw InputError("--set " + assignment + ": '" + sofar.substr(0, sofar.rfind('.')) + "' is a value, not a table");
    }
  }
  // steps and t_end are two ways to give a run's end (run.steps, or a [[stage]]'s steps): a --set
  // of one replaces the file's other (both given by --set stay, and the reader refuses them as it
  // refuses both in the file).
  if (parts.size() >= 2 && (parts.back() == "steps" || parts.back() == "t_end")) {
    const std::string table = key.substr(0, key.rfind('.'));
    const std::string other = parts.back() == "steps" ? "t_end" : "steps";
    toml::table* t = nullptr;
    if (table == "run") {
      t = table_->get_as<toml::table>("run");
    } else if (parts.size() == 3 && parts[0] == "stage") {
      if (auto* stages = table_->get_as<toml::array>("stage")) {
        char* end = nullptr;
        const long idx = std::strtol(parts[1].c_str(), &end, 10);
        if (*end == '\0' && idx >= 0 && idx < static_cast<long>(stages->size())) t = stages->get(idx)->as_table();
      }
    }
    if (t && !overridden_.count(table + "." + other)) t->erase(other);
  }
  overridden_.insert(key);
}

double Deck::evaluate(const std::string& expr, const std::string& where) const {
  try {
    mu::Parser p;
    p.DefineConst("pi", M_PI);
    for (const auto& [name, v] : variables_) p.DefineConst(name, v);
    p.SetExpr(expr);
    const double v = p.Eval();
    if (std::isnan(v))
      throw InputError(where + ": expression \"" + expr +
                       "\" evaluates to nan (0/0, or sqrt or log of a negative number?); expected a finite number");
    if (!std::isfinite(v))
      throw InputError(where + ": expression \"" + expr + "\" evaluates to " + (v > 0 ? "inf" : "-inf") +
                       " (division by zero or overflow?); expected a finite number");
    return v;
  } catch (const mu::Parser::exception_type& e) {
    // Most often a name that is not a variable: say which (a syntax error is reported as such).
    for (const std::string& used : referenced_names(expr, where))
      if (!variables_.count(used))
        throw InputError(where + ": expression \"" + expr + "\" refers to '" + used +
                         "', which is not a variable (define it under [variables])");
    throw InputError(where + ": cannot evaluate expression \"" + expr + "\": " + e.GetMsg());
  }
}

std::set<std::string> Deck::referenced_names(const std::string& expr, const std::string& where) const {
  try {
    mu::Parser p;
    p.DefineConst("pi", M_PI);
    p.SetExpr(expr);
    std::set<std::string> out;
    for (const auto& [name, ptr] : p.GetUsedVar()) out.insert(name);  // undefined ones included
    return out;
  } catch (const mu::Parser::exception_type& e) {
    throw InputError(where + ": cannot evaluate expression \"" + expr + "\": " + e.GetMsg());
  }
}

void Deck::resolve_variables() {
  const toml::node* node = table_->get("variables");
  if (!node) return;
  const toml::table* vars = node->as_table();
  if (!vars) throw InputError(location(node, "variables") + ": variables: expected a table of name = value");
  // Variables may refer to each other in any order: resolve in passes until no progress.
  std::map<std::string, const toml::node*> pending;
  for (const auto& [k, v] : *vars) {
    const std::string name(k.str());
    const std::string where = location(&v, "variables." + name) + ": variables." + name;
    if (!valid_identifier(name) || name == "pi")
      throw InputError(where + ": a variable name must be an identifier (letters, digits, _) other than pi");
    if (v.is_integer() || v.is_floating_point()) {
      const double x = as_double(v);
      if (!std::isfinite(x)) throw InputError(where + ": expected a finite number, got " + shown(v));
      variables_[name] = x;
    } else if (v.is_string()) {
      mark_expression(&v);
      pending[name] = &v;
    } else {
      throw InputError(where + ": expected a number or an expression string, got " + type_word(v));
    }
  }
  while (!pending.empty()) {
    bool progress = false;
    for (auto it = pending.begin(); it != pending.end();) {
      try {
        const double x = evaluate(*it->second->value<std::string>(), "");
        variables_[it->first] = x;
        it = pending.erase(it);
        progress = true;
      } catch (const InputError&) {
        ++it;
      }
    }
    if (!progress) {
      // Say why: an undefined name, an expression that fails on its own (1/0, a syntax error),
      // or else a cycle through the pending variables.
      for (const auto& [name, v] : pending) {
        const std::string expr = *v->value<std::string>();
        const std::string where = location(v, "variables." + name) + ": variables." + name;
        bool waits = false;
        for (const std::string& used : referenced_names(expr, where)) {
          if (variables_.count(used)) continue;
          if (!pending.count(used))
            throw InputError(where + ": expression \"" + expr + "\" refers to '" + used +
                             "', which is not a variable (define it under [variables])");
          waits = true;
        }
        if (!waits) evaluate(expr, where);  // throws the expression's own error
      }
      const auto& [name, v] = *pending.begin();
      throw InputError(location(v, "variables." + name) + ": variables." + name + ": cannot resolve \"" +
                       *v->value<std::string>() + "\": it refers, through other variables, to itself");
    }
  }
}

// ---------------------------------------------------------------------------------------
// DeckTable

DeckTable::DeckTable(const Deck* deck, const toml::table* table, std::string path)
    : deck_(deck), table_(table), path_(std::move(path)) {}

std::string DeckTable::key_path(std::string_view key) const {
  return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
}

bool DeckTable::has(std::string_view key) const {
  known_.emplace(key);  // a key the reader asks about is one this table takes
  return table_->contains(key);
}

bool DeckTable::is_array(std::string_view key) const {
  known_.emplace(key);
  const toml::node* n = table_->get(key);
  return n && n->is_array();
}

bool DeckTable::has_retired(std::string_view key) const {
  return table_->contains(key);
}

const toml::node* DeckTable::get(std::string_view key) {
  known_.emplace(key);
  const toml::node* n = table_->get(key);
  if (n) used_.emplace(key);
  return n;
}

void DeckTable::fail(std::string_view key, const std::string& what, const std::vector<std::string>& related) const {
  throw InputError(where(key, related) + ": " + what);
}

void DeckTable::fail_here(const std::string& what, const std::vector<std::string>& related) const {
  throw InputError(deck_->location(table_, path_, related) + ": " + (path_.empty() ? "deck" : shown_key(path_)) + ": " +
                   what);
}

std::string DeckTable::where() const {
  return deck_->location(table_, path_) + ": " + (path_.empty() ? "deck" : shown_key(path_));
}

std::string DeckTable::where(std::string_view key, const std::vector<std::string>& related) const {
  const std::string kp = key_path(key);
  return deck_->location(table_->get(key), kp, related) + ": " + shown_key(kp);
}

std::string DeckTable::shown_key(const std::string& kp) const {
  return deck_->shown_path(kp);
}

double DeckTable::to_number(const toml::node& n, const std::string& kp) const {
  if (n.is_string()) deck_->mark_expression(&n);  // its variables are where its value came from
  const std::string where = deck_->location(&n, kp) + ": " + shown_key(kp);
  double x;
  if (n.is_integer() || n.is_floating_point()) {
    x = as_double(n);
    if (!std::isfinite(x)) throw InputError(where + ": expected a finite number, got " + shown(n));
  } else if (n.is_string()) {
    x = deck_->evaluate(*n.value<std::string>(), where);
  } else {
    throw InputError(where + ": expected a number or an expression string, got " + type_word(n));
  }
  // The window every deck number must lie in: the kernels multiply a few of them (α²/ε², m g·x,
  // r² …), and a value near the largest double, or a subnormal one, overflows there only later —
  // at step 1, with no key to name. Reduced units have no business outside it.
  const double a = std::abs(x);
  if (a > kLargestDeckNumber || (a != 0.0 && a < kSmallestDeckNumber))
    throw InputError(where + ": " + format_exact(x) + " is outside the range of deck numbers (0, or " +
                     format_exact(kSmallestDeckNumber) + " .. " + format_exact(kLargestDeckNumber) +
                     " in magnitude); expected a value in reduced units");
  return x;
}

std::optional<double> DeckTable::maybe_number(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return std::nullopt;
  return to_number(*n, key_path(key));
}

double DeckTable::number(std::string_view key) {
  if (auto v = maybe_number(key)) return *v;
  missing(key, "missing required key '" + std::string(key) + "'");
}

double DeckTable::number(std::string_view key, double fallback) {
  return maybe_number(key).value_or(fallback);
}

std::optional<long> DeckTable::maybe_integer(std::string_view key) {
  auto v = maybe_number(key);
  if (!v) return std::nullopt;
  if (*v != std::floor(*v)) fail(key, "expected an integer, got " + format_exact(*v));
  if (std::abs(*v) > 9.0e15) fail(key, "expected an integer of magnitude at most 9e15, got " + format_exact(*v));
  return static_cast<long>(*v);
}

long DeckTable::integer(std::string_view key) {
  if (auto v = maybe_integer(key)) return *v;
  missing(key, "missing required key '" + std::string(key) + "'");
}

long DeckTable::integer(std::string_view key, long fallback) {
  return maybe_integer(key).value_or(fallback);
}

std::string DeckTable::string(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) missing(key, "missing required key '" + std::string(key) + "'");
  if (!n->is_string()) fail(key, "expected a string, got " + type_word(*n));
  return *n->value<std::string>();
}

std::string DeckTable::string(std::string_view key, std::string fallback) {
  return has(key) ? string(key) : (known_.emplace(key), std::move(fallback));
}

std::string DeckTable::name(std::string_view key) {
  std::string s = string(key);
  if (s.empty()) fail(key, "expected a non-empty name");
  return s;
}

std::string DeckTable::name(std::string_view key, std::string fallback) {
  return has(key) ? name(key) : (known_.emplace(key), std::move(fallback));
}

bool DeckTable::boolean(std::string_view key, bool fallback) {
  const toml::node* n = get(key);
  if (!n) return fallback;
  if (!n->is_boolean()) fail(key, "expected true or false, got " + shown(*n));
  return *n->value<bool>();
}

Eigen::Vector3d DeckTable::vector3(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) missing(key, "missing required key '" + std::string(key) + "'");
  const toml::array* a = n->as_array();
  if (!a) fail(key, "expected an array of 3 numbers, got " + shown(*n));
  if (a->size() != 3) fail(key, "expected an array of 3 numbers, got " + std::to_string(a->size()));
  Eigen::Vector3d v;
  for (int k = 0; k < 3; ++k) v[k] = to_number(*a->get(k), key_path(key) + "[" + std::to_string(k) + "]");
  return v;
}

Eigen::Vector3d DeckTable::vector3(std::string_view key, const Eigen::Vector3d& fallback) {
  return has(key) ? vector3(key) : (known_.emplace(key), fallback);
}

Eigen::Vector3i DeckTable::bool3(std::string_view key, bool fallback) {
  const toml::node* n = get(key);
  if (!n) return Eigen::Vector3i::Constant(fallback ? 1 : 0);
  if (n->is_boolean()) return Eigen::Vector3i::Constant(*n->value<bool>() ? 1 : 0);
  const toml::array* a = n->as_array();
  if (!a || a->size() != 3) fail(key, "expected true/false or an array of 3 booleans, got " + shown(*n));
  Eigen::Vector3i v;
  for (int k = 0; k < 3; ++k) {
    if (!a->get(k)->is_boolean()) fail(key, "expected an array of 3 booleans, got " + shown(*a->get(k)));
    v[k] = *a->get(k)->value<bool>() ? 1 : 0;
  }
  return v;
}

std::vector<long> DeckTable::integers(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) missing(key, "missing required key '" + std::string(key) + "'");
  const toml::array* a = n->as_array();
  if (!a) fail(key, "expected an array of integers, got " + shown(*n));
  std::vector<long> out;
  for (size_t k = 0; k < a->size(); ++k) {
    const toml::node* e = a->get(k);
    if (!e->is_integer())
      fail(key, "expected an array of integers, element " + std::to_string(k) + " is " + type_word(*e));
    out.push_back(static_cast<long>(*e->value<int64_t>()));
  }
  return out;
}

std::vector<double> DeckTable::numbers(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return {};
  const toml::array* a = n->as_array();
  if (!a) fail(key, "expected an array of numbers, got " + shown(*n));
  std::vector<double> out;
  for (size_t k = 0; k < a->size(); ++k)
    out.push_back(to_number(*a->get(k), key_path(key) + "[" + std::to_string(k) + "]"));
  return out;
}

std::vector<std::string> DeckTable::strings(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return {};
  const toml::array* a = n->as_array();
  if (!a) fail(key, "expected an array of strings, got " + shown(*n));
  std::vector<std::string> out;
  for (size_t k = 0; k < a->size(); ++k) {
    if (!a->get(k)->is_string())
      fail(key, "expected an array of strings, element " + std::to_string(k) + " is " + type_word(*a->get(k)));
    out.push_back(*a->get(k)->value<std::string>());
  }
  return out;
}

std::vector<std::pair<std::string, std::string>> DeckTable::string_map(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return {};
  const toml::table* t = n->as_table();
  if (!t) fail(key, "expected a table of names, e.g. { \"1\" = \"bead\" }, got " + type_word(*n));
  std::vector<std::pair<std::string, std::string>> out;
  for (const auto& [k, v] : *t) {
    if (!v.is_string()) fail(key, "expected a name (string) for '" + std::string(k.str()) + "', got " + type_word(v));
    out.emplace_back(std::string(k.str()), *v.value<std::string>());
    if (out.back().second.empty()) fail(key, "expected a non-empty name for '" + out.back().first + "'");
  }
  return out;
}

namespace {

// A value as TOML text that parses back to the same value: a float in its shortest round-trip
// form (with a decimal point, so that it stays a float), anything else as toml++ prints it.
std::string toml_text(const toml::node& n) {
  if (const auto x = n.value_exact<double>()) {
    char buf[64];
    const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, *x);
    std::string s(buf, ec == std::errc() ? end : buf);
    if (std::isfinite(*x) && s.find_first_of(".e") == std::string::npos) s += ".0";
    return s;
  }
  std::ostringstream o;
  n.visit([&](const auto& v) { o << v; });
  return o.str();
}

}  // namespace

std::vector<DeckTable::ValueList> DeckTable::value_lists(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return {};
  if (!n->is_table()) fail(key, "expected a table of lists, e.g. { \"thermostat.seed\" = [1, 2] }, got " + shown(*n));
  std::vector<ValueList> out;
  const auto flatten = [&](const auto& self, const toml::table& t, const std::string& prefix) -> void {
    for (const auto& [k, v] : t) {
      const std::string name = prefix + std::string(k.str());
      if (const toml::table* sub = v.as_table()) {
        self(self, *sub, name + ".");
        continue;
      }
      const std::string kp = key_path(key) + "." + name;
      const toml::array* a = v.as_array();
      if (!a) throw InputError(deck_->location(&v, kp) + ": " + kp + ": expected a list of values, got " + shown(v));
      if (a->empty()) throw InputError(deck_->location(&v, kp) + ": " + kp + ": expected a non-empty list of values");
      ValueList list{name, deck_->location(&v, kp), {}};
      for (const toml::node& e : *a) {
        if (e.is_table())
          throw InputError(list.where + ": " + kp + ": expected a list of values, got a table among them");
        list.values.push_back(toml_text(e));
      }
      out.push_back(std::move(list));
    }
  };
  flatten(flatten, *n->as_table(), "");
  return out;
}

std::optional<DeckTable> DeckTable::table(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return std::nullopt;
  if (!n->is_table()) fail(key, "expected a table, got " + type_word(*n));
  return DeckTable(deck_, n->as_table(), key_path(key));
}

std::vector<std::pair<std::string, DeckTable>> DeckTable::named_tables() {
  std::vector<std::pair<std::string, DeckTable>> out;
  for (const auto& [k, v] : *table_) {
    const std::string name(k.str());
    used_.insert(name);
    if (name.empty()) fail(name, "expected a name, got an empty one: [" + key_path("\"\"") + "]");
    if (!v.is_table()) fail(name, "expected a table [" + key_path(name) + "], got " + type_word(v));
    out.emplace_back(name, DeckTable(deck_, v.as_table(), key_path(name)));
  }
  return out;
}

std::vector<DeckTable> DeckTable::array_of_tables(std::string_view key) {
  const toml::node* n = get(key);
  if (!n) return {};
  const toml::array* a = n->as_array();
  if (!a) fail(key, "expected an array of tables [[" + key_path(key) + "]], got " + type_word(*n));
  std::vector<DeckTable> out;
  for (size_t k = 0; k < a->size(); ++k) {
    const toml::node* e = a->get(k);
    const std::string kp = key_path(key) + "[" + std::to_string(k) + "]";
    if (!e->is_table())
      throw InputError(deck_->location(e, kp) + ": " + shown_key(kp) + ": expected a table, got " + type_word(*e));
    out.emplace_back(deck_, e->as_table(), kp);
  }
  return out;
}

namespace {

// Edit distance with transpositions (optimal string alignment): a typo is one or two of
// insertions, deletions, substitutions and swaps of neighbours.
std::size_t typo_distance(std::string_view a, std::string_view b) {
  std::vector<std::vector<std::size_t>> d(a.size() + 1, std::vector<std::size_t>(b.size() + 1));
  for (std::size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (std::size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i)
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  return d[a.size()][b.size()];
}

// Whether `typed` is plausibly a misspelling of `meant`: at most one edit in five characters
// (TOML keys are case-sensitive: another case is a misspelling too); keys shorter than four
// characters only in another case, since one edit of them is often another valid key — unless
// the names compared with are all the names there are (`every_name`).
bool looks_like(std::string_view typed, std::string_view meant, bool every_name = false) {
  if (every_name && (typed.size() < 4 || meant.size() < 4) && typed != meant) return typo_distance(typed, meant) <= 1;
  if (typed.size() < 4 || meant.size() < 4) {  // x, y, h, K, k, r0, R0: one edit is another key
    if (typed.size() != meant.size() || typed == meant) return false;
    for (std::size_t i = 0; i < typed.size(); ++i)
      if (std::tolower(static_cast<unsigned char>(typed[i])) != std::tolower(static_cast<unsigned char>(meant[i])))
        return false;
    return true;
  }
  const std::size_t limit = std::max<std::size_t>(1, std::max(typed.size(), meant.size()) / 5);
  return typo_distance(typed, meant) <= limit;
}

}  // namespace

std::string nearest_name(std::string_view typed, const std::vector<std::string>& known, bool every_name) {
  std::string nearest;
  std::size_t best = std::string::npos;
  for (const std::string& name : known) {
    const std::size_t d = typo_distance(typed, name);
    if (d < best && looks_like(typed, name, every_name)) best = d, nearest = name;
  }
  return nearest;
}

void DeckTable::finish() const {
  for (const auto& [k, v] : *table_) {
    if (used_.count(k.str())) continue;
    const std::string kp = key_path(k.str());
    // A key the table already sets is rarely what another key of the same file meant (a style's
    // key copied beside the one this style takes); a --set is how a set key is overridden, so
    // there it is the likeliest meaning of all.
    const bool from_set = !deck_->override_of(kp).empty();
    std::string expected;
    std::vector<std::string> candidates;
    for (const auto& name : known_) {
      expected += (expected.empty() ? "" : ", ") + name;
      if (from_set || !table_->contains(name)) candidates.push_back(name);
    }
    const std::string nearest = nearest_name(k.str(), candidates);
    throw InputError(
        deck_->location(&v, kp) + ": " + shown_key(kp) + ": unknown key" +
        (nearest.empty() ? "" : "; did you mean '" + nearest + "'?") +
        (expected.empty() ? std::string(" (this table takes no keys)") : " (expected one of: " + expected + ")"));
  }
}

void DeckTable::missing(std::string_view key, const std::string& what) const {
  for (const auto& [k, v] : *table_)
    if (!used_.count(k.str()) && looks_like(k.str(), key)) {
      const std::string kp = key_path(k.str());
      throw InputError(deck_->location(&v, kp) + ": " + shown_key(kp) + ": unknown key; did you mean '" +
                       std::string(key) + "'? (" + what + ")");
    }
  fail_here(what);
}

}  // namespace stiffmd
