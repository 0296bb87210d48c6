#pragma once
/// \file
/// Small text helpers for error messages.
#include <string>
#include <vector>

namespace terramap {

/// Levenshtein edit distance.
int editDistance(const std::string& a, const std::string& b);
/// Up to `max` candidates closest to `word` (edit distance <= max(2, |word|/3)), best first.
std::vector<std::string> closestMatches(const std::string& word, const std::vector<std::string>& candidates,
                                        int max = 3);
/// " (did you mean 'x'?)" or "" when nothing is close.
std::string didYouMean(const std::string& word, const std::vector<std::string>& candidates);
/// "a, b, c"
std::string joinStrings(const std::vector<std::string>& items, const std::string& sep = ", ");
/// FNV-1a 64-bit hash of `bytes` as 16 lower-case hex digits: a stable fingerprint of a
/// configuration's text (not a cryptographic hash).
std::string fnv1a64Hex(const std::string& bytes);
/// A double with 17 significant digits (round-trips exactly), for messages and metadata.
std::string formatNumber(double v);

}  // namespace terramap
