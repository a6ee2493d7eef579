// Device facts the properties need beyond the register table: which value of
// which command register saves or factory-resets, and how a position move is
// commanded and observed. They are the spec's `operations:` section
// (spec/README.md, spec::Operations), registers named by key, each citing its
// section; so a fifth drive gets the persistence and motion properties from
// its spec alone.
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
  return o.save || o.factory_reset || o.motion ? &o : nullptr;
}

}  // namespace mbc::conf::props
