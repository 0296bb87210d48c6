#include <terramap/core/error.hpp>

#include <sstream>

namespace terramap {

// Out-of-line key functions: the vtables and typeinfo live in libterramap_core only, so a
// plugin's throw is caught by type in the host.
Error::~Error() = default;
const char* Error::kind() const noexcept { return "error"; }
#define TERRAMAP_ERROR_KIND(Cls, name)      \
  Cls::~Cls() = default;                    \
  const char* Cls::kind() const noexcept { return name; }
TERRAMAP_ERROR_KIND(ConfigError, "config")
TERRAMAP_ERROR_KIND(InputError, "input")
TERRAMAP_ERROR_KIND(PluginError, "plugin")
TERRAMAP_ERROR_KIND(LayerError, "layer")
TERRAMAP_ERROR_KIND(OutputError, "output")
#undef TERRAMAP_ERROR_KIND
TileBudgetError::~TileBudgetError() = default;
InternalError::~InternalError() = default;

}  // namespace terramap

namespace terramap::detail {

void checkFailed(const char* expr, const char* file, int line, const std::string& msg) {
  std::ostringstream os;
  os << "internal check failed: " << expr << " at " << file << ":" << line;
  if (!msg.empty()) os << ": " << msg;
  throw InternalError(os.str());
}

}  // namespace terramap::detail
