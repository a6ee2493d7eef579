#include "session/gate.h"

#include <fmt/core.h>

#include <algorithm>
#include <set>

#include "modbus/crc16.h"
#include "modbus/rtu.h"

namespace mbc::conf {
namespace {

uint16_t be16(std::span<const uint8_t> p, size_t at) { return uint16_t(p[at] << 8 | p[at + 1]); }

// The register table's quantity limits (MBAP v1.1b3 §6.11, §6.12, §6.17): a
// request claiming more is refused by a conforming server; the range kept
// covers the most a server could take from it.
constexpr int kMaxWriteRegisters = 123, kMaxWriteCoils = 1968;

}  // namespace

std::optional<WriteRange> writes_of(std::span<const uint8_t> pdu) {
  if (pdu.size() < 3) return std::nullopt;
  const uint16_t address = be16(pdu, 1);
  auto quantity = [&](int most) {
    int q = pdu.size() >= 5 ? be16(pdu, 3) : 1;
    return std::clamp(q, 1, most);
  };
  switch (pdu[0]) {
    case 0x05: return WriteRange{spec::Table::coil, address, 1};
    case 0x06: return WriteRange{spec::Table::holding, address, 1};
    case 0x0F: return WriteRange{spec::Table::coil, address, quantity(kMaxWriteCoils)};
    case 0x10: return WriteRange{spec::Table::holding, address, quantity(kMaxWriteRegisters)};
    case 0x16: return WriteRange{spec::Table::holding, address, 1};
    case 0x17:  // read/write multiple: the write part follows the read's address and quantity (§6.17)
      if (pdu.size() < 7) return std::nullopt;
      return WriteRange{spec::Table::holding, be16(pdu, 5),
                        std::clamp(pdu.size() >= 9 ? int(be16(pdu, 7)) : 1, 1, 121)};
    default: return std::nullopt;
  }
}

std::vector<std::pair<uint8_t, Bytes>> frames_in(Framing framing, std::span<const uint8_t> bytes, std::optional<size_t> gap_after) {
  std::vector<std::pair<uint8_t, Bytes>> out;
  auto scan = [&](std::span<const uint8_t> b) {
    if (framing == &mbc::kTcp) {
      // A receiver takes unit and PDU after the 7-byte header, up to the length it states.
      if (b.size() < 8) return;
      size_t len = be16(b, 4);
      size_t end = std::min(b.size(), 6 + std::max<size_t>(len, 1));
      if (end > 7) out.emplace_back(b[6], Bytes(b.begin() + 7, b.begin() + long(end)));
      return;
    }
    // RTU: every prefix whose CRC holds is a frame to a receiver that frames by length.
    for (size_t n = 4; n <= b.size(); ++n)
      if (crc_ok(b.first(n))) {
        auto pdu = mbc::kRtu.pdu_bytes(b.first(n));
        out.emplace_back(b[0], Bytes(pdu.begin(), pdu.end()));
      }
  };
  scan(bytes);
  if (gap_after && *gap_after > 0 && *gap_after < bytes.size()) {
    scan(bytes.first(*gap_after));
    scan(bytes.subspan(*gap_after));
  }
  return out;
}

std::optional<Refusal> Gate::check(uint8_t unit, std::span<const uint8_t> pdu) const {
  if (!info_.live) return std::nullopt;
  auto w = writes_of(pdu);
  if (!w) return std::nullopt;
  const int fc = pdu[0];
  if (unit == 0) {
    if (!rules_.policy.allow_broadcast)
      return Refusal{fmt::format("FC {:02X} to unit 0: a broadcast write reaches every drive on the line and only unit {} "
                                 "can be restored: needs --allow-broadcast", fc, info_.unit),
                     "--allow-broadcast"};
  } else if (unit != info_.unit) {
    return Refusal{fmt::format("FC {:02X} to unit {}: a write to a drive other than the target's unit {} is never sent "
                               "(it could not be restored)", fc, unit, info_.unit),
                   ""};
  }
  if (!spec_) return Refusal{fmt::format("FC {:02X}: no spec says what may be written on this target", fc), ""};
  if (rules_.access_unstated && !rules_.allow_writes)
    return Refusal{fmt::format("FC {:02X} at 0x{:04X}: the map in use states no access: needs --allow-writes", fc, w->address),
                   "--allow-writes"};
  std::set<const spec::Register*> seen;
  for (int k = 0; k < w->count; ++k) {
    const uint32_t a = uint32_t(w->address) + uint32_t(k);
    if (a > 0xFFFF) break;
    const spec::Register* r = spec_->register_covering(uint16_t(a), w->table);
    if (!r || !seen.insert(r).second) continue;
    if (w->table == spec::Table::holding) {
      for (const auto& st : spec_->serial.settings)
        if (st.register_address == r->address)
          return Refusal{fmt::format("FC {:02X} at 0x{:04X}: sets the {}; never written on a live line", fc, r->address,
                                     st.setting),
                         ""};
      for (const auto& other : spec_->registers)
        if (other.persistence.unless_register && *other.persistence.unless_register == r->address &&
            !rules_.policy.allow_eeprom_writes)
          return Refusal{fmt::format("FC {:02X} at 0x{:04X}: the \"do not persist\" switch, held on while the command "
                                     "writes: needs --allow-eeprom-writes", fc, r->address),
                         "--allow-eeprom-writes"};
    }
    WriteDecision d = may_write(*spec_, *r, info_, rules_.policy);
    if (!d.allowed) {
      std::string opt = d.reason.find("--allow-motion") != std::string::npos ? "--allow-motion"
                        : d.reason.find("--allow-eeprom-writes") != std::string::npos ? "--allow-eeprom-writes"
                                                                                       : "";
      return Refusal{fmt::format("FC {:02X}: {}", fc, d.reason), opt};
    }
  }
  return std::nullopt;
}

}  // namespace mbc::conf
