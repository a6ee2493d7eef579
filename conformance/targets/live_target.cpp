// tcp://, rtu-tcp://, rtu://: a live device. One file per transport
// (tcp_target.cpp, rtu_target.cpp); what they share is in live_link.h.
#include <stdexcept>

#include "targets/kinds.h"
#include "targets/live_link.h"

namespace mbc::conf {

std::unique_ptr<Target> make_modbus_target(const Uri& u) {
  if (u.scheme == "tcp") return make_tcp_target(u);
  return make_rtu_target(u);  // rtu, rtu-tcp
}

}  // namespace mbc::conf
