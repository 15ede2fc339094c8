#include "engine/scene/ensemble_deck.hpp"

#include "core/errors.hpp"

namespace stiffmd {

std::vector<std::string> Ensemble::overrides(int k) const {
  std::vector<std::string> out;
  for (const auto& list : varied) out.push_back(list.key + "=" + list.values[k]);
  return out;
}

std::string Ensemble::label(int k) const {
  std::string out;
  for (const std::string& o : overrides(k)) out += (out.empty() ? "" : " ") + o;
  return out;
}

std::optional<Ensemble> read_ensemble(DeckTable& root) {
  auto t = root.table("ensemble");
  if (!t) return std::nullopt;
  Ensemble e{t->where(), t->value_lists("vary")};
  if (e.varied.empty())
    t->missing("vary", "expected vary = { \"KEY\" = [value, ...], ... }: the members' --set values");
  for (const auto& list : e.varied) {
    if (list.values.size() != e.varied.front().values.size())
      throw InputError(list.where + ": ensemble.vary." + list.key + ": expected " +
                       std::to_string(e.varied.front().values.size()) + " values (as " + e.varied.front().key +
                       " has), got " + std::to_string(list.values.size()));
    if (list.key.rfind("ensemble.", 0) == 0 || list.key == "ensemble")
      throw InputError(list.where + ": ensemble.vary." + list.key + ": the ensemble cannot vary itself");
  }
  t->finish();
  return e;
}

}  // namespace stiffmd
