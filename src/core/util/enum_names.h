// Name tables of enums: one table of (value, name) pairs gives both a value's name (for output,
// JSON and messages) and the value a name on the command line or in a file stands for.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

#include "util/error.h"

namespace kdgrid {

/// One entry of an enum's name table.
template <class E>
struct EnumName {
  E value;
  const char* name;
};

/// The name `table` gives `value`, or `fallback` where the table does not list it.
template <class E, size_t N>
constexpr const char* enum_name(E value, const EnumName<E> (&table)[N],
                                const char* fallback = "?") {
  for (const EnumName<E>& e : table)
    if (e.value == value) return e.name;
  return fallback;
}

/// The value `table` names `name`, or nothing where no entry has that name.
template <class E, size_t N>
constexpr std::optional<E> enum_value(std::string_view name, const EnumName<E> (&table)[N]) {
  for (const EnumName<E>& e : table)
    if (name == e.name) return e.value;
  return std::nullopt;
}

/// The value `table` names `text`; otherwise a ParamError "WHAT 'TEXT': CHOICES", where
/// `choices` says which names there are.
template <class E, size_t N>
E parse_enum(const std::string& text, const EnumName<E> (&table)[N], const std::string& what,
             const char* choices) {
  if (const auto v = enum_value(text, table)) return *v;
  throw ParamError(what + " '" + text + "': " + choices);
}

}  // namespace kdgrid
