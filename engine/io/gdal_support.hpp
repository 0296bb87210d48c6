#pragma once
// Internal to terramap_io (GDAL is a private dependency): shared by geotiff.cpp and render.cpp.
#include <gdal_priv.h>
#include <cpl_conv.h>
#include <cpl_error.h>

#include <mutex>
#include <string>

namespace terramap::io::detail {

/// Registers GDAL's drivers once per process (GDALAllRegister is not safe to race).
inline void ensureGdalRegistered() {
  static std::once_flag once;
  std::call_once(once, [] { GDALAllRegister(); });
}

/// Collects GDAL's errors on this thread instead of letting GDAL print them to stderr (a
/// library must not write to the terminal), so they can go into the exception we throw.
/// GDAL error handlers are per thread, so concurrent exports on other threads are unaffected.
class GdalErrorCapture {
 public:
  GdalErrorCapture() { CPLPushErrorHandlerEx(&GdalErrorCapture::handler, this); }
  ~GdalErrorCapture() { CPLPopErrorHandler(); }
  GdalErrorCapture(const GdalErrorCapture&) = delete;
  GdalErrorCapture& operator=(const GdalErrorCapture&) = delete;

  bool failed() const { return failed_; }
  /// "GDAL: <first failure>; <second> ..." or "" when GDAL reported no failure.
  std::string message() const { return messages_.empty() ? std::string() : "GDAL: " + messages_; }

 private:
  static void CPL_STDCALL handler(CPLErr cls, CPLErrorNum, const char* msg) {
    auto* self = static_cast<GdalErrorCapture*>(CPLGetErrorHandlerUserData());
    if (cls < CE_Failure) return;  // debug/warning chatter is not an error
    self->failed_ = true;
    if (!self->messages_.empty()) self->messages_ += "; ";
    self->messages_ += msg ? msg : "(no message)";
  }
  bool failed_ = false;
  std::string messages_;
};

/// Sets a GDAL configuration option for this thread only, restoring the old value afterwards.
class ScopedGdalOption {
 public:
  ScopedGdalOption(const char* key, const char* value) : key_(key) {
    const char* old = CPLGetThreadLocalConfigOption(key, nullptr);
    had_old_ = old != nullptr;
    if (had_old_) old_ = old;
    CPLSetThreadLocalConfigOption(key, value);
  }
  ~ScopedGdalOption() { CPLSetThreadLocalConfigOption(key_.c_str(), had_old_ ? old_.c_str() : nullptr); }
  ScopedGdalOption(const ScopedGdalOption&) = delete;
  ScopedGdalOption& operator=(const ScopedGdalOption&) = delete;

 private:
  std::string key_, old_;
  bool had_old_ = false;
};

}  // namespace terramap::io::detail
