#include <terramap/plugin/params.hpp>

#include <cmath>
#include <sstream>

namespace terramap {

const char* paramTypeName(ParamType t) {
  switch (t) {
    case ParamType::Bool: return "bool";
    case ParamType::Int: return "integer";
    case ParamType::Double: return "number";
    case ParamType::String: return "string";
    case ParamType::DoubleList: return "list of numbers";
    case ParamType::StringList: return "list of strings";
  }
  return "?";
}

std::string paramTypeWithArticle(ParamType t) {
  const std::string n = paramTypeName(t);
  const bool vowel = !n.empty() && std::string("aeiou").find(n[0]) != std::string::npos;
  return (vowel ? "an " : "a ") + n;
}

std::string showParamValue(const ParamValue& v) {
  return std::visit(
      [](const auto& x) -> std::string {
        using T = std::decay_t<decltype(x)>;
        std::ostringstream os;
        if constexpr (std::is_same_v<T, bool>) os << (x ? "true" : "false");
        else if constexpr (std::is_same_v<T, long> || std::is_same_v<T, double>) os << x;
        else if constexpr (std::is_same_v<T, std::string>) os << "'" << x << "'";
        else {
          os << "[";
          for (size_t i = 0; i < x.size(); ++i) {
            if (i) os << ", ";
            if constexpr (std::is_same_v<typename T::value_type, std::string>) os << "'" << x[i] << "'";
            else os << x[i];
          }
          os << "]";
        }
        return os.str();
      },
      v);
}

namespace param {
ParamSpec real(std::string name, double def, double min, double max, std::string unit, std::string doc) {
  ParamSpec s{std::move(name), ParamType::Double, ParamValue(def), min, max, std::move(unit), std::move(doc), {}, -1};
  return s;
}
ParamSpec realRequired(std::string name, double min, double max, std::string unit, std::string doc) {
  return ParamSpec{std::move(name), ParamType::Double, std::nullopt, min, max, std::move(unit), std::move(doc), {}, -1};
}
ParamSpec integer(std::string name, long def, long min, long max, std::string doc) {
  return ParamSpec{std::move(name), ParamType::Int, ParamValue(def), static_cast<double>(min),
                   static_cast<double>(max), "1", std::move(doc), {}, -1};
}
ParamSpec boolean(std::string name, bool def, std::string doc) {
  return ParamSpec{std::move(name), ParamType::Bool, ParamValue(def), 0, 1, "", std::move(doc), {}, -1};
}
ParamSpec text(std::string name, std::string def, std::vector<std::string> choices, std::string doc) {
  ParamSpec s{std::move(name), ParamType::String, ParamValue(std::move(def)), 0, 0, "", std::move(doc),
              std::move(choices), -1};
  return s;
}
ParamSpec path(std::string name, std::string def, std::string doc) {
  return ParamSpec{std::move(name), ParamType::String, ParamValue(std::move(def)), 0, 0, "path", std::move(doc), {}, -1};
}
ParamSpec reals(std::string name, std::vector<double> def, int size, double min, double max, std::string unit,
                std::string doc) {
  return ParamSpec{std::move(name), ParamType::DoubleList, ParamValue(std::move(def)), min, max,
                   std::move(unit), std::move(doc), {}, size};
}
ParamSpec texts(std::string name, std::vector<std::string> def, std::string doc) {
  return ParamSpec{std::move(name), ParamType::StringList, ParamValue(std::move(def)), 0, 0, "", std::move(doc),
                   {}, -1};
}
}  // namespace param

namespace {
std::string fmt(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}
std::string rangeText(const ParamSpec& s) {
  return "[" + fmt(s.min) + ", " + fmt(s.max) + "]";
}
std::string checkNumber(const ParamSpec& s, double v) {
  if (!std::isfinite(v)) return "must be a finite number (got " + fmt(v) + ")";
  if (v < s.min || v > s.max) return "must be in " + rangeText(s) + " (got " + fmt(v) + ")";
  return {};
}
std::string checkChoice(const ParamSpec& s, const std::string& v) {
  if (s.choices.empty()) return {};
  for (const auto& c : s.choices)
    if (c == v) return {};
  std::string all;
  for (size_t i = 0; i < s.choices.size(); ++i) all += (i ? ", " : "") + s.choices[i];
  return "must be one of {" + all + "} (got '" + v + "')";
}
}  // namespace

std::string checkParamValue(const ParamSpec& spec, const ParamValue& v) {
  switch (spec.type) {
    case ParamType::Bool:
      return std::holds_alternative<bool>(v) ? "" : std::string("must be a bool (true/false)") + " (got " + showParamValue(v) + ")";
    case ParamType::Int:
      if (!std::holds_alternative<long>(v)) return std::string("must be an integer") + " (got " + showParamValue(v) + ")";
      return checkNumber(spec, static_cast<double>(std::get<long>(v)));
    case ParamType::Double:
      if (std::holds_alternative<long>(v)) return checkNumber(spec, static_cast<double>(std::get<long>(v)));
      if (!std::holds_alternative<double>(v)) return std::string("must be a number") + " (got " + showParamValue(v) + ")";
      return checkNumber(spec, std::get<double>(v));
    case ParamType::String:
      if (!std::holds_alternative<std::string>(v)) return std::string("must be a string") + " (got " + showParamValue(v) + ")";
      return checkChoice(spec, std::get<std::string>(v));
    case ParamType::DoubleList: {
      if (!std::holds_alternative<std::vector<double>>(v)) return std::string("must be a list of numbers") + " (got " + showParamValue(v) + ")";
      const auto& l = std::get<std::vector<double>>(v);
      if (spec.list_size >= 0 && static_cast<int>(l.size()) != spec.list_size)
        return "must have " + std::to_string(spec.list_size) + " items (got " + std::to_string(l.size()) + ")";
      for (size_t i = 0; i < l.size(); ++i) {
        auto m = checkNumber(spec, l[i]);
        if (!m.empty()) return "item " + std::to_string(i) + " " + m;
      }
      return {};
    }
    case ParamType::StringList: {
      if (!std::holds_alternative<std::vector<std::string>>(v)) return std::string("must be a list of strings") + " (got " + showParamValue(v) + ")";
      for (const auto& s : std::get<std::vector<std::string>>(v)) {
        auto m = checkChoice(spec, s);
        if (!m.empty()) return m;
      }
      return {};
    }
  }
  return "unknown type";
}

const ParamValue& Params::value(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end())
    throw InternalError(owner_ + ": plugin asked for parameter '" + name + "' that its schema does not declare");
  return it->second;
}

bool Params::getBool(const std::string& name) const {
  const auto& v = value(name);
  if (auto p = std::get_if<bool>(&v)) return *p;
  throw InternalError(owner_ + ": parameter '" + name + "' is not a bool");
}
long Params::getInt(const std::string& name) const {
  const auto& v = value(name);
  if (auto p = std::get_if<long>(&v)) return *p;
  throw InternalError(owner_ + ": parameter '" + name + "' is not an integer");
}
double Params::getDouble(const std::string& name) const {
  const auto& v = value(name);
  if (auto p = std::get_if<double>(&v)) return *p;
  if (auto p = std::get_if<long>(&v)) return static_cast<double>(*p);
  throw InternalError(owner_ + ": parameter '" + name + "' is not a number");
}
const std::string& Params::getString(const std::string& name) const {
  const auto& v = value(name);
  if (auto p = std::get_if<std::string>(&v)) return *p;
  throw InternalError(owner_ + ": parameter '" + name + "' is not a string");
}
const std::vector<double>& Params::getDoubles(const std::string& name) const {
  const auto& v = value(name);
  if (auto p = std::get_if<std::vector<double>>(&v)) return *p;
  throw InternalError(owner_ + ": parameter '" + name + "' is not a list of numbers");
}
const std::vector<std::string>& Params::getStrings(const std::string& name) const {
  const auto& v = value(name);
  if (auto p = std::get_if<std::vector<std::string>>(&v)) return *p;
  throw InternalError(owner_ + ": parameter '" + name + "' is not a list of strings");
}

std::string Params::where(const std::string& name) const {
  auto it = where_.find(name);
  if (it != where_.end() && !it->second.empty()) return it->second;
  return owner_ + ".params." + name + " (default)";
}

void Params::fail(const std::string& name, const std::string& message) const {
  throw ConfigError(where(name) + ": " + message);
}

void Params::report(const std::string& name, const std::string& message) const {
  reported_.push_back(where(name) + ": " + message);
}

void Params::throwIfReported() const {
  if (reported_.empty()) return;
  std::string all;
  for (const auto& e : reported_) all += (all.empty() ? "" : "\n") + e;
  throw ConfigError(all);
}

void Params::set(const std::string& name, ParamValue v, std::string where) {
  // Numbers declared Double but written as integers (sigma: 1) are stored as double.
  for (const auto& s : schema_)
    if (s.name == name && s.type == ParamType::Double && std::holds_alternative<long>(v))
      v = static_cast<double>(std::get<long>(v));
  values_[name] = std::move(v);
  if (!where.empty()) where_[name] = std::move(where);
}

Params makeParams(const std::string& owner, const ParamSchema& schema,
                  const std::map<std::string, ParamValue>& overrides) {
  Params p(owner, schema);
  std::vector<std::string> errors;
  for (const auto& [k, v] : overrides) {
    const ParamSpec* spec = nullptr;
    for (const auto& s : schema)
      if (s.name == k) spec = &s;
    if (!spec) {
      errors.push_back(owner + ".params." + k + ": unknown parameter");
      continue;
    }
    const auto m = checkParamValue(*spec, v);
    if (!m.empty()) errors.push_back(owner + ".params." + k + ": " + m);
    else p.set(k, v, owner + ".params." + k);
  }
  for (const auto& s : schema) {
    if (overrides.count(s.name)) continue;
    if (s.default_value) p.set(s.name, *s.default_value);
    else errors.push_back(owner + ".params." + s.name + ": required parameter is missing");
  }
  if (!errors.empty()) {
    std::string all;
    for (const auto& e : errors) all += (all.empty() ? "" : "\n") + e;
    throw ConfigError(all);
  }
  return p;
}

}  // namespace terramap
