#include "erratum_extra.h"

#include <mutex>

namespace mbc::spec {
namespace {

std::mutex& lock() {
  static std::mutex m;
  return m;
}
std::map<std::string, std::map<std::string, ErratumExtra>>& registry() {
  static std::map<std::string, std::map<std::string, ErratumExtra>> r;
  return r;
}

}  // namespace

void record_erratum_extras(const std::string& path, std::map<std::string, ErratumExtra> extras) {
  std::lock_guard<std::mutex> g(lock());
  registry()[path] = std::move(extras);
}

ErratumExtra erratum_extra(const Spec& s, const std::string& id) {
  std::lock_guard<std::mutex> g(lock());
  auto it = registry().find(s.path);
  if (it == registry().end()) return {};
  auto e = it->second.find(id);
  return e == it->second.end() ? ErratumExtra{} : e->second;
}

}  // namespace mbc::spec
