#include <terramap/core/error.hpp>

#include <sstream>

namespace terramap::detail {

void checkFailed(const char* expr, const char* file, int line, const std::string& msg) {
  std::ostringstream os;
  os << "internal check failed: " << expr << " at " << file << ":" << line;
  if (!msg.empty()) os << ": " << msg;
  throw InternalError(os.str());
}

}  // namespace terramap::detail
