// plugin:PATH.so: a vendor stack through the plugin C ABI (being written).
#include <stdexcept>

#include "targets/kinds.h"

namespace mbc::conf {
std::unique_ptr<Target> make_plugin_target(const Uri& u) {
  throw std::runtime_error("target kind 'plugin' is not built yet");
}
}  // namespace mbc::conf
