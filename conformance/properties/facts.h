// Device facts the properties need beyond the register table: which value of
// which command register saves or factory-resets (the spec's `operations:`,
// spec::Operations), and how a position move is commanded and observed (the
// spec's `control.motion`, spec::MotionOperations); registers named by key,
// each citing its section; so a fifth drive gets the persistence and motion
// properties from its spec alone.
#pragma once

#include "spec.h"

namespace mbc::conf::props {

using CommandFact = spec::RegisterWrite;
using MotionFacts = spec::MotionOperations;
using DeviceFacts = spec::Operations;

// The spec's operations; nullptr when it states none. The pointer lives as
// long as `spec`.
inline const DeviceFacts* facts_for(const spec::Spec& spec) {
  const auto& o = spec.operations;
  return o.save || o.factory_reset ? &o : nullptr;
}

// The spec's control.motion; nullptr when it states none.
inline const MotionFacts* motion_facts(const spec::Spec& spec) {
  return spec.control && spec.control->motion ? &*spec.control->motion : nullptr;
}

}  // namespace mbc::conf::props
