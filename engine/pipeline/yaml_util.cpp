#include "yaml_util.hpp"

namespace terramap::yaml {

RawParam toRaw(Diagnostics& d, const YAML::Node& n, const std::string& path) {
  RawParam r;
  r.where = d.at(n, path);
  if (n.IsScalar()) {
    bool b;
    long l;
    double x;
    if (scalarBool(n, b)) r.value = b;
    else if (scalarLong(n, l)) r.value = l;
    else if (scalarDouble(n, x)) r.value = x;
    else r.value = n.Scalar();
    return r;
  }
  if (n.IsSequence()) {
    std::vector<double> nums;
    std::vector<std::string> strs;
    bool all_num = true;
    for (const auto& it : n) {
      double x;
      if (!it.IsScalar()) {
        r.is_map = true;  // nested structures are never valid plugin params
        return r;
      }
      if (scalarDouble(it, x)) nums.push_back(x);
      else all_num = false;
      strs.push_back(it.Scalar());
    }
    if (all_num && !nums.empty()) r.value = nums;
    else r.value = strs;
    return r;
  }
  if (n.IsNull()) {
    r.value = std::string();
    return r;
  }
  r.is_map = true;
  return r;
}

std::map<std::string, RawParam> toRawMap(Diagnostics& d, const YAML::Node& n, const std::string& path) {
  std::map<std::string, RawParam> out;
  if (!n) return out;
  if (!n.IsMap()) {
    d.error(n, path, "must be a mapping of key: value");
    return out;
  }
  for (const auto& kv : n) {
    std::string k;
    if (!keyName(d, kv.first, path, k)) continue;
    RawParam r = toRaw(d, kv.second, subPath(path, k));
    r.where = d.at(kv.first, subPath(path, k));  // the key's position: what a reader looks for
    out[k] = r;
  }
  return out;
}

}  // namespace terramap::yaml
