#include <terramap/pipeline/plugin_schema.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/core/text.hpp>

#include "elf_section.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstring>
#include <cmath>
#include <sstream>

namespace terramap {

namespace {

using nlohmann::json;

const char* accessKey(LayerAccess a) {
  switch (a) {
    case LayerAccess::Read: return "read";
    case LayerAccess::Write: return "write";
    case LayerAccess::Create: return "create";
  }
  return "read";
}

const char* typeKey(ParamType t) {
  switch (t) {
    case ParamType::Bool: return "bool";
    case ParamType::Int: return "int";
    case ParamType::Double: return "double";
    case ParamType::String: return "string";
    case ParamType::DoubleList: return "double_list";
    case ParamType::StringList: return "string_list";
  }
  return "double";
}

/// JSON has no infinity: unbounded ranges are written as the strings "inf" and "-inf".
json number(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return v;
}

json valueJson(const ParamValue& v) {
  return std::visit(
      [](const auto& x) -> json {
        using T = std::decay_t<decltype(x)>;
        if constexpr (std::is_same_v<T, double>) return number(x);
        else if constexpr (std::is_same_v<T, std::vector<double>>) {
          json a = json::array();
          for (double d : x) a.push_back(number(d));
          return a;
        } else return x;
      },
      v);
}

/// Reading with the file and the field named in every refusal.
struct Reader {
  const std::string& what;
  [[noreturn]] void fail(const std::string& field, const std::string& why) const {
    throw InputError(what + ": embedded plugin schema: " + field + ": " + why);
  }
  const json& at(const json& o, const char* key, const std::string& field) const {
    if (!o.is_object() || !o.contains(key)) fail(field + "." + key, "missing");
    return o.at(key);
  }
  std::string str(const json& o, const char* key, const std::string& field) const {
    const json& v = at(o, key, field);
    if (!v.is_string()) fail(field + "." + key, "must be a string");
    return v.get<std::string>();
  }
  double num(const json& v, const std::string& field) const {
    if (v.is_number()) return v.get<double>();
    if (v == "inf") return std::numeric_limits<double>::infinity();
    if (v == "-inf") return -std::numeric_limits<double>::infinity();
    fail(field, "must be a number");
  }
  std::vector<std::string> strings(const json& v, const std::string& field) const {
    if (!v.is_array()) fail(field, "must be a list of strings");
    std::vector<std::string> out;
    for (const json& s : v) {
      if (!s.is_string()) fail(field, "must be a list of strings");
      out.push_back(s.get<std::string>());
    }
    return out;
  }
  ParamValue value(ParamType t, const json& v, const std::string& field) const {
    switch (t) {
      case ParamType::Bool:
        if (!v.is_boolean()) fail(field, "must be a boolean");
        return v.get<bool>();
      case ParamType::Int:
        if (!v.is_number_integer()) fail(field, "must be an integer");
        return v.get<long>();
      case ParamType::Double: return num(v, field);
      case ParamType::String:
        if (!v.is_string()) fail(field, "must be a string");
        return v.get<std::string>();
      case ParamType::DoubleList: {
        if (!v.is_array()) fail(field, "must be a list of numbers");
        std::vector<double> out;
        for (const json& d : v) out.push_back(num(d, field));
        return out;
      }
      case ParamType::StringList: return strings(v, field);
    }
    fail(field, "unknown type");
  }
};

ParamType typeFromKey(const Reader& r, const std::string& key, const std::string& field) {
  for (ParamType t : {ParamType::Bool, ParamType::Int, ParamType::Double, ParamType::String, ParamType::DoubleList,
                      ParamType::StringList})
    if (key == typeKey(t)) return t;
  r.fail(field, "unknown parameter type '" + key + "'");
}

LayerAccess accessFromKey(const Reader& r, const std::string& key, const std::string& field) {
  for (LayerAccess a : {LayerAccess::Read, LayerAccess::Write, LayerAccess::Create})
    if (key == accessKey(a)) return a;
  r.fail(field, "unknown layer access '" + key + "'");
}

// ---- probing (build time) --------------------------------------------------------------------

/// Parses one probe value given to the build ("KEY=VALUE") as `spec`'s type.
ParamValue parseProbeValue(const ParamSpec& spec, const std::string& text, const std::string& where) {
  auto items = [&]() {
    std::string t = text;
    if (t.size() < 2 || t.front() != '[' || t.back() != ']') throw ConfigError(where + ": a list is written [a, b]");
    t = t.substr(1, t.size() - 2);
    std::vector<std::string> out;
    std::stringstream ss(t);
    std::string item;
    while (std::getline(ss, item, ',')) {
      const auto a = item.find_first_not_of(' '), b = item.find_last_not_of(' ');
      if (a != std::string::npos) out.push_back(item.substr(a, b - a + 1));
    }
    return out;
  };
  try {
    switch (spec.type) {
      case ParamType::Bool:
        if (text == "true" || text == "false") return text == "true";
        throw ConfigError(where + ": must be true or false");
      case ParamType::Int: return std::stol(text);
      case ParamType::Double: return std::stod(text);
      case ParamType::String: return text;
      case ParamType::DoubleList: {
        std::vector<double> out;
        for (const auto& s : items()) out.push_back(std::stod(s));
        return out;
      }
      case ParamType::StringList: return items();
    }
  } catch (const std::logic_error&) {  // stol/stod
    throw ConfigError(where + ": '" + text + "' is not " + paramTypeWithArticle(spec.type));
  }
  throw ConfigError(where + ": unknown type");
}

/// A value for a parameter without default that the build gave no probe value for: inside the
/// range, the first choice, or a name (configure() may still refuse it; the build then says so).
ParamValue standInValue(const ParamSpec& s) {
  const double inside = std::clamp(0.0, s.min, s.max);
  switch (s.type) {
    case ParamType::Bool: return false;
    case ParamType::Int: return static_cast<long>(std::ceil(inside));
    case ParamType::Double: return inside;
    case ParamType::String: return s.choices.empty() ? "probe_" + s.name : s.choices.front();
    case ParamType::DoubleList: return std::vector<double>(static_cast<size_t>(std::max(0, s.list_size)), inside);
    case ParamType::StringList: return s.choices.empty() ? std::vector<std::string>{} : s.choices;
  }
  return false;
}

/// Configures a fresh instance per probe, so no probe sees what an earlier one left behind.
struct Probe {
  const std::string& path;
  const std::string& type;
  const ParamSchema& schema;

  /// The layers configure(values) leads to, or nullopt when configure() refuses the values.
  std::optional<std::vector<LayerSpec>> layersAt(const std::map<std::string, ParamValue>& values,
                                                 std::string* why = nullptr) const {
    PluginHandle plugin = PluginRegistry::createFromFile(path, type);
    Params p(type, schema);
    for (const auto& [k, v] : values) p.set(k, v);
    try {
      plugin->configure(p);
    } catch (const std::exception& e) {
      if (why) *why = e.what();
      return std::nullopt;
    }
    if (!p.reported().empty()) {
      if (why) *why = p.reported().front();
      return std::nullopt;
    }
    return plugin->layers();
  }
};

bool sameLayers(const std::vector<LayerSpec>& a, const std::vector<LayerSpec>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (a[i].name != b[i].name || a[i].access != b[i].access) return false;
  return true;
}

/// Splits `name` at each occurrence of the sentinels (param -> sentinel) into a template.
std::vector<LayerTemplate::Part> templateOf(const std::string& name, const std::map<std::string, std::string>& sentinels) {
  std::vector<LayerTemplate::Part> parts;
  std::string literal;
  for (size_t i = 0; i < name.size();) {
    bool matched = false;
    for (const auto& [param, s] : sentinels)
      if (name.compare(i, s.size(), s) == 0) {
        if (!literal.empty()) parts.push_back({literal, false});
        literal.clear();
        parts.push_back({param, true});
        i += s.size();
        matched = true;
        break;
      }
    if (!matched) literal += name[i++];
  }
  if (!literal.empty()) parts.push_back({literal, false});
  return parts;
}

/// The layer `t` names at `values` (every parameter it uses has a string value there).
LayerSpec evaluate(const LayerTemplate& t, const std::map<std::string, ParamValue>& values) {
  LayerSpec l;
  for (const auto& part : t.name) l.name += part.is_param ? std::get<std::string>(values.at(part.text)) : part.text;
  l.access = t.access;
  l.unit = t.unit;
  return l;
}

bool usesParam(const LayerTemplate& t, const std::string& p) {
  return std::any_of(t.name.begin(), t.name.end(), [&](const LayerTemplate::Part& x) { return x.is_param && x.text == p; });
}

}  // namespace

// ---- JSON --------------------------------------------------------------------------------------

std::string descriptionToJson(const PluginDescription& d) {
  json params = json::array();
  for (const ParamSpec& s : d.params) {
    json p = {{"name", s.name}, {"type", typeKey(s.type)}, {"min", number(s.min)}, {"max", number(s.max)},
              {"unit", s.unit}, {"doc", s.doc}, {"choices", s.choices}, {"list_size", s.list_size}};
    if (s.default_value) p["default"] = valueJson(*s.default_value);
    params.push_back(std::move(p));
  }
  json probe = json::object();
  for (const auto& [k, v] : d.probe) probe[k] = valueJson(v);
  const auto layersJson = [](const std::vector<LayerTemplate>& templates) {
    json layers = json::array();
    for (const LayerTemplate& t : templates) {
      json name = json::array();
      for (const auto& part : t.name) name.push_back(part.is_param ? json{{"param", part.text}} : json(part.text));
      layers.push_back(
          {{"name", name}, {"access", accessKey(t.access)}, {"unit", t.unit}, {"unless_empty", t.unless_empty}});
    }
    return layers;
  };
  json variants = json::array();
  for (const auto& v : d.variants)
    variants.push_back({{"param", v.param}, {"value", valueJson(v.value)}, {"layers", layersJson(v.layers)}});
  const json j = {{"format", PluginDescription::kFormat}, {"type", d.type}, {"version", d.version},
                  {"build_id", d.build_id}, {"params", params}, {"probe", probe}, {"layers", layersJson(d.layers)},
                  {"variants", variants}, {"layers_vary_with", d.layers_vary_with}};
  return j.dump();
}

PluginDescription descriptionFromJson(const std::string& text, const std::string& what) {
  const Reader r{what};
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    r.fail("(text)", std::string("not JSON: ") + e.what());
  }
  const json& format = r.at(j, "format", "");
  if (!format.is_number_integer() || format.get<long>() != PluginDescription::kFormat)
    r.fail(".format", "format " + format.dump() + ", this terramap reads " + std::to_string(PluginDescription::kFormat));
  PluginDescription d;
  d.type = r.str(j, "type", "");
  d.version = r.str(j, "version", "");
  d.build_id = r.str(j, "build_id", "");
  const json& params = r.at(j, "params", "");
  if (!params.is_array()) r.fail(".params", "must be a list");
  for (size_t i = 0; i < params.size(); ++i) {
    const std::string f = ".params[" + std::to_string(i) + "]";
    const json& p = params[i];
    ParamSpec s;
    s.name = r.str(p, "name", f);
    s.type = typeFromKey(r, r.str(p, "type", f), f + ".type");
    s.min = r.num(r.at(p, "min", f), f + ".min");
    s.max = r.num(r.at(p, "max", f), f + ".max");
    s.unit = r.str(p, "unit", f);
    s.doc = r.str(p, "doc", f);
    s.choices = r.strings(r.at(p, "choices", f), f + ".choices");
    const json& n = r.at(p, "list_size", f);
    if (!n.is_number_integer()) r.fail(f + ".list_size", "must be an integer");
    s.list_size = n.get<int>();
    if (p.contains("default")) s.default_value = r.value(s.type, p.at("default"), f + ".default");
    d.params.push_back(std::move(s));
  }
  auto specOf = [&](const std::string& name) {
    const auto it = std::find_if(d.params.begin(), d.params.end(), [&](const ParamSpec& s) { return s.name == name; });
    return it == d.params.end() ? nullptr : &*it;
  };
  const json& probe = r.at(j, "probe", "");
  if (!probe.is_object()) r.fail(".probe", "must be a mapping");
  for (const auto& [k, v] : probe.items()) {
    const ParamSpec* s = specOf(k);
    if (!s) r.fail(".probe." + k, "not a declared parameter");
    d.probe[k] = r.value(s->type, v, ".probe." + k);
  }
  const auto layersOf = [&](const json& layers, const std::string& field) {
    if (!layers.is_array()) r.fail(field, "must be a list");
    std::vector<LayerTemplate> out;
    for (size_t i = 0; i < layers.size(); ++i) {
      const std::string f = field + "[" + std::to_string(i) + "]";
      LayerTemplate t;
      const json& name = r.at(layers[i], "name", f);
      if (!name.is_array()) r.fail(f + ".name", "must be a list");
      for (const json& part : name) {
        if (part.is_string()) {
          t.name.push_back({part.get<std::string>(), false});
          continue;
        }
        const std::string param = r.str(part, "param", f + ".name");
        const ParamSpec* s = specOf(param);
        if (!s || s->type != ParamType::String) r.fail(f + ".name", "'" + param + "' is not a string parameter");
        t.name.push_back({param, true});
      }
      t.access = accessFromKey(r, r.str(layers[i], "access", f), f + ".access");
      t.unit = r.str(layers[i], "unit", f);
      t.unless_empty = r.strings(r.at(layers[i], "unless_empty", f), f + ".unless_empty");
      for (const auto& p : t.unless_empty)
        if (!specOf(p) || specOf(p)->type != ParamType::String)
          r.fail(f + ".unless_empty", "'" + p + "' is not a string parameter");
      out.push_back(std::move(t));
    }
    return out;
  };
  d.layers = layersOf(r.at(j, "layers", ""), ".layers");
  const json& variants = r.at(j, "variants", "");
  if (!variants.is_array()) r.fail(".variants", "must be a list");
  for (size_t i = 0; i < variants.size(); ++i) {
    const std::string f = ".variants[" + std::to_string(i) + "]";
    PluginDescription::Variant v;
    v.param = r.str(variants[i], "param", f);
    const ParamSpec* s = specOf(v.param);
    if (!s) r.fail(f + ".param", "'" + v.param + "' is not a declared parameter");
    v.value = r.value(s->type, r.at(variants[i], "value", f), f + ".value");
    v.layers = layersOf(r.at(variants[i], "layers", f), f + ".layers");
    d.variants.push_back(std::move(v));
  }
  d.layers_vary_with = r.strings(r.at(j, "layers_vary_with", ""), ".layers_vary_with");
  for (const auto& p : d.layers_vary_with)
    if (!specOf(p)) r.fail(".layers_vary_with", "'" + p + "' is not a declared parameter");
  return d;
}

// ---- evaluation (validate time) -----------------------------------------------------------------

std::optional<std::vector<LayerSpec>> layersFromDescription(const PluginDescription& d,
                                                            const std::map<std::string, ParamValue>& values,
                                                            std::string& why) {
  for (const auto& p : d.layers_vary_with) {
    const auto v = values.find(p), probed = d.probe.find(p);
    if (v == values.end() || probed == d.probe.end() || !(v->second == probed->second)) {
      why = "its layers depend on '" + p + "' in a way its embedded schema does not describe (described at " + p +
            ": " + (probed == d.probe.end() ? std::string("?") : showParamValue(probed->second)) + ")";
      return std::nullopt;
    }
  }
  const std::vector<LayerTemplate>* templates = &d.layers;
  std::string other;  // the parameter whose variant is used
  for (const auto& var : d.variants) {
    const auto v = values.find(var.param), probed = d.probe.find(var.param);
    if (v == values.end() || probed == d.probe.end() || v->second == probed->second || !(v->second == var.value))
      continue;
    if (!other.empty() && other != var.param) {
      why = "its layers depend on both '" + other + "' and '" + var.param + "', and its embedded schema describes "
            "them for one of the two at a time";
      return std::nullopt;
    }
    other = var.param;
    templates = &var.layers;
  }
  auto stringOf = [&](const std::string& p) -> const std::string* {
    const auto v = values.find(p);
    return v == values.end() ? nullptr : std::get_if<std::string>(&v->second);
  };
  std::vector<LayerSpec> out;
  for (const LayerTemplate& t : *templates) {
    bool present = true;
    for (const auto& p : t.unless_empty) {
      const std::string* s = stringOf(p);
      if (!s) {
        why = "its layers are named by '" + p + "', which has no value";
        return std::nullopt;
      }
      present = present && !s->empty();
    }
    if (!present) continue;
    LayerSpec l;
    for (const auto& part : t.name) {
      if (!part.is_param) {
        l.name += part.text;
        continue;
      }
      const std::string* s = stringOf(part.text);
      if (!s) {
        why = "its layers are named by '" + part.text + "', which has no value";
        return std::nullopt;
      }
      l.name += *s;
    }
    l.access = t.access;
    l.unit = t.unit;
    out.push_back(std::move(l));
  }
  return out;
}

std::string elfBuildId(const std::string& path) {
  const auto note = detail::readElfSection(path, ".note.gnu.build-id", 1024);
  // Elf_Nhdr: namesz, descsz, type (4 bytes each), the name "GNU\0", then the descriptor.
  if (!note || note->size() < 16) return {};
  std::uint32_t namesz = 0, descsz = 0;
  std::memcpy(&namesz, note->data(), 4);
  std::memcpy(&descsz, note->data() + 4, 4);
  const std::size_t desc_at = 12 + ((namesz + 3u) & ~3u);
  if (descsz == 0 || desc_at > note->size() || descsz > note->size() - desc_at) return {};
  static const char* hex = "0123456789abcdef";
  std::string out;
  for (std::size_t i = 0; i < descsz; ++i) {
    const auto b = static_cast<unsigned char>((*note)[desc_at + i]);
    out += hex[b >> 4];
    out += hex[b & 15];
  }
  return out;
}

// ---- describePlugin (build time) ------------------------------------------------------------------

PluginDescription describePlugin(const std::string& path, const std::vector<std::string>& probe_values) {
  PluginHandle h = PluginRegistry::createFromFile(path);
  PluginDescription d;
  d.type = h.type();
  d.version = h.version();
  d.build_id = elfBuildId(path);
  if (d.build_id.empty())
    throw PluginError(path + ": no GNU build-id note: the embedded schema is bound to the build by it "
                      "(link with -Wl,--build-id, as terramap_add_plugin does)");
  d.params = h->schema();
  const ParamSchema& schema = d.params;
  auto specOf = [&](const std::string& name) -> const ParamSpec* {
    const auto it = std::find_if(schema.begin(), schema.end(), [&](const ParamSpec& s) { return s.name == name; });
    return it == schema.end() ? nullptr : &*it;
  };

  // The baseline: defaults, the build's probe values, stand-ins for the rest.
  for (const ParamSpec& s : schema) d.probe[s.name] = s.default_value ? *s.default_value : standInValue(s);
  for (const std::string& kv : probe_values) {
    const auto eq = kv.find('=');
    const ParamSpec* s = eq == std::string::npos ? nullptr : specOf(kv.substr(0, eq));
    if (!s) throw PluginError(path + ": probe value '" + kv + "': expected KEY=VALUE with a parameter of '" + d.type + "'");
    ParamValue v = parseProbeValue(*s, kv.substr(eq + 1), path + ": probe value '" + kv + "'");
    if (const std::string m = checkParamValue(*s, v); !m.empty())
      throw PluginError(path + ": probe value '" + kv + "': " + m);
    d.probe[s->name] = std::move(v);
  }
  const Probe probe{path, d.type, schema};
  std::string why;
  const auto base = probe.layersAt(d.probe, &why);
  if (!base)
    throw PluginError(path + ": configure() refuses the probe values (" + why + "): give values that configure "
                      "with terramap_add_plugin(" + d.type + " ... SCHEMA_PARAMS KEY=VALUE ...), or NO_SCHEMA");

  // String parameters that name layers: each set on its own to a sentinel, then all at once.
  std::map<std::string, std::string> sentinels;
  std::map<std::string, std::vector<LayerSpec>> single, emptied;
  std::vector<std::string> vary;
  int k = 0;
  for (const ParamSpec& s : schema) {
    if (s.type != ParamType::String || !s.choices.empty()) continue;
    const std::string sentinel = "terramap_probe_" + std::to_string(k++) + "_";
    auto values = d.probe;
    values[s.name] = sentinel;
    const auto with = probe.layersAt(values);
    if (!with) continue;  // refuses other text: a name it checks itself, not a layer name
    if (sameLayers(*with, *base)) continue;
    sentinels[s.name] = sentinel;
    single[s.name] = *with;
    values[s.name] = std::string();
    if (const auto e = probe.layersAt(values)) emptied[s.name] = *e;
  }
  std::vector<LayerSpec> joint = *base;
  if (!sentinels.empty()) {
    auto values = d.probe;
    for (const auto& [p, s] : sentinels) values[p] = s;
    const auto j = probe.layersAt(values);
    if (j) joint = *j;
  }
  for (const LayerSpec& l : joint) {
    LayerTemplate t;
    t.name = templateOf(l.name, sentinels);
    t.access = l.access;
    t.unit = l.unit;
    d.layers.push_back(std::move(t));
  }
  // A layer named by a parameter that is absent where the parameter is empty exists "unless empty".
  for (const auto& [p, layers] : emptied) {
    auto values = d.probe;
    values[p] = std::string();
    for (auto& t : d.layers) {
      if (!usesParam(t, p)) continue;
      const LayerSpec l = evaluate(t, values);
      const bool kept = std::any_of(layers.begin(), layers.end(),
                                    [&](const LayerSpec& x) { return x.name == l.name && x.access == l.access; });
      if (!kept) t.unless_empty.push_back(p);
    }
  }
  // The description must reproduce every probe; what it does not is declared as unknown.
  auto reproduces = [&](const std::map<std::string, ParamValue>& values, const std::vector<LayerSpec>& actual) {
    std::string unused;
    const auto predicted = layersFromDescription(d, values, unused);
    return predicted && sameLayers(*predicted, actual);
  };
  bool templates_hold = reproduces(d.probe, *base);
  for (const auto& [p, layers] : single) {
    auto values = d.probe;
    values[p] = sentinels[p];
    templates_hold = templates_hold && reproduces(values, layers);
  }
  for (const auto& [p, layers] : emptied) {
    auto values = d.probe;
    values[p] = std::string();
    templates_hold = templates_hold && reproduces(values, layers);
  }
  if (!templates_hold) {
    d.layers.clear();
    for (const LayerSpec& l : *base) d.layers.push_back({{{l.name, false}}, l.access, l.unit, {}});
    for (const auto& [p, s] : sentinels) vary.push_back(p);
  }
  // Every other parameter: its other values must leave the layers as described.
  for (const ParamSpec& s : schema) {
    if (sentinels.count(s.name) && templates_hold) continue;
    std::vector<ParamValue> others;
    switch (s.type) {
      case ParamType::Bool: others.push_back(!std::get<bool>(d.probe[s.name])); break;
      case ParamType::Int:
        for (double e : {s.min, s.max})
          if (std::isfinite(e)) others.push_back(static_cast<long>(e));
        break;
      case ParamType::Double:
        for (double e : {s.min, s.max})
          if (std::isfinite(e)) others.push_back(e);
        break;
      case ParamType::String:
        for (const auto& c : s.choices) others.push_back(c);
        if (s.choices.empty()) others.push_back(std::string("terramap_probe_other"));
        break;
      case ParamType::StringList:
        others.push_back(s.choices.empty() ? std::vector<std::string>{"terramap_probe_item"}
                                           : std::vector<std::string>{s.choices.back()});
        break;
      case ParamType::DoubleList: break;
    }
    // A parameter of few values whose other value changes the layers gets the layers at that
    // value, named by the string parameters as above where that holds, else it varies.
    const bool few = s.type == ParamType::Bool || (s.type == ParamType::String && !s.choices.empty());
    std::vector<PluginDescription::Variant> found;
    bool varies = false;
    for (const ParamValue& v : others) {
      if (v == d.probe[s.name] || !checkParamValue(s, v).empty()) continue;
      auto values = d.probe;
      values[s.name] = v;
      const auto got = probe.layersAt(values);
      if (!got || reproduces(values, *got)) continue;
      if (!few) {
        varies = true;
        break;
      }
      PluginDescription::Variant var{s.name, v, {}};
      auto with_sentinels = values;
      for (const auto& [p, sentinel] : sentinels) with_sentinels[p] = sentinel;
      const auto joint_v = templates_hold ? probe.layersAt(with_sentinels) : got;
      for (const LayerSpec& l : joint_v ? *joint_v : *got)
        var.layers.push_back({templateOf(l.name, templates_hold ? sentinels : std::map<std::string, std::string>{}),
                              l.access, l.unit, {}});
      for (auto& t : var.layers)  // optional inputs stay optional where the main layers say so
        for (const auto& m : d.layers)
          if (m.name.size() == t.name.size() && std::equal(m.name.begin(), m.name.end(), t.name.begin(),
                  [](const LayerTemplate::Part& a, const LayerTemplate::Part& b) {
                    return a.is_param == b.is_param && a.text == b.text;
                  }))
            t.unless_empty = m.unless_empty;
      PluginDescription one = d;
      one.variants = {var};
      std::string unused;
      const auto predicted = layersFromDescription(one, values, unused);
      if (!predicted || !sameLayers(*predicted, *got)) {
        varies = true;
        break;
      }
      found.push_back(std::move(var));
    }
    if (varies) {
      if (std::find(vary.begin(), vary.end(), s.name) == vary.end()) vary.push_back(s.name);
    } else {
      for (auto& v : found) d.variants.push_back(std::move(v));
    }
  }
  d.layers_vary_with = vary;
  return d;
}

}  // namespace terramap
