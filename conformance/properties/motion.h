// Motion on the virtual clock: position moves end exactly at the target,
// speed never exceeds the configured maximum, the status word agrees with the
// motion, an emergency stop is immediate, a normal stop ends within the
// deceleration time, and a drive that needs homing refuses positioning
// before it. Registers and commands come from the spec (keys) and the
// device facts (facts.h), never from the reference code.
#pragma once

#include <vector>

#include "properties/properties.h"

namespace mbc::conf::props {

std::vector<Invariant> motion_invariants();

}  // namespace mbc::conf::props
