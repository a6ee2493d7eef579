#include "properties/motion.h"

namespace mbc::conf::props {

std::vector<Invariant> motion_invariants() { return {}; }

}  // namespace mbc::conf::props
