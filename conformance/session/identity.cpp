#include "session/identity.h"

#include <fmt/core.h>

#include <algorithm>
#include <set>

namespace mbc::conf {

bool IdentityRead::refused() const {
  return kind == Kind::silent || kind == Kind::not_sent || (kind == Kind::exception && (exception == 1 || exception == 2));
}

std::optional<uint16_t> IdentityRead::word() const {
  if (kind != Kind::answered || pdu.size() < 4) return std::nullopt;
  return uint16_t(pdu[2] << 8 | pdu[3]);
}

std::string Identity::objects_text() const {
  auto get = [&](int k) {
    auto it = objects.find(k);
    return it == objects.end() ? std::string() : it->second;
  };
  return fmt::format("FC 43/14: VendorName \"{}\", ProductCode \"{}\", Revision \"{}\"", get(0), get(1), get(2));
}

bool identifies_by_fc43(const spec::Spec& s) {
  const auto* f = s.profile.function(43);
  return f && std::find(f->mei_types.begin(), f->mei_types.end(), 14) != f->mei_types.end() &&
         !s.device.identification.product_code.empty();
}

std::vector<const spec::Register*> identity_registers(const spec::Spec& s, bool stated_only) {
  std::vector<const spec::Register*> out;
  std::set<std::string> declarations;
  for (const auto& r : s.registers) {
    if (r.table != spec::Table::holding && r.table != spec::Table::input) continue;
    if (r.access == spec::Access::wo || r.access == spec::Access::command || r.command) continue;
    const auto* f = s.profile.function(r.table == spec::Table::holding ? 3 : 4);
    if (!f) continue;
    if (stated_only && (r.basis_of(spec::Fact::read).basis != spec::Basis::stated || f->basis_of("supported").is_inferred())) continue;
    if (!r.origin.empty() && !declarations.insert(r.origin).second) continue;
    out.push_back(&r);
  }
  return out;
}

Identity read_identity(const spec::Spec& s, const IdentityAsk& ask, const IdentityOptions& o) {
  Identity id;
  if (o.fc43 && identifies_by_fc43(s)) {
    // Read Device Identification, basic stream (MBAP v1.1b3 §6.21).
    id.by_fc43 = true;
    std::string error;
    if (auto r = ask(read_device_identification(1, 0), error); r && r->pdu) id.objects = device_identification(*r->pdu);
    return id;
  }
  const auto regs = identity_registers(s, o.stated_only);
  const size_t samples = std::min(o.samples, regs.size());
  for (size_t k = 0; k < samples; ++k) {
    IdentityRead read;
    read.reg = regs[k * regs.size() / samples];
    read.fc = read.reg->table == spec::Table::holding ? 3 : 4;
    const Bytes req = read_request(read.fc, read.reg->address, uint16_t(read.reg->words));
    for (int attempt = 0; attempt < std::max(1, o.attempts); ++attempt) {
      read.error.clear();
      auto got = ask(req, read.error);
      if (!got) {
        read.kind = IdentityRead::Kind::not_sent;
        continue;
      }
      if (got->silent()) {
        read.kind = IdentityRead::Kind::silent;
        continue;
      }
      if (!got->pdu) {
        read.kind = IdentityRead::Kind::malformed;
        continue;
      }
      read.pdu = *got->pdu;
      const Bytes& p = read.pdu;
      if (p.size() >= 2 && p[0] == (read.fc | 0x80)) {
        read.kind = IdentityRead::Kind::exception;
        read.exception = p[1];
      } else if (p.size() == size_t(2 + 2 * read.reg->words) && p[0] == read.fc && p[1] == 2 * read.reg->words) {
        read.kind = IdentityRead::Kind::answered;
      } else {
        read.kind = IdentityRead::Kind::malformed;
      }
      break;
    }
    id.reads.push_back(std::move(read));
  }
  return id;
}

}  // namespace mbc::conf
