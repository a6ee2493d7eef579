// tcp://, rtu-tcp://, rtu://: a live device through libmodbus (being written).
#include <stdexcept>

#include "targets/kinds.h"

namespace mbc::conf {
std::unique_ptr<Target> make_modbus_target(const Uri& u) {
  throw std::runtime_error("target kind '" + u.scheme + "' is not built yet");
}
}  // namespace mbc::conf
