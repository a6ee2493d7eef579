#include "fuzz_support.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <memory>

#include "loader.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/limits.h"

namespace mbc::fuzz {

const std::vector<spec::Spec>& specs() {
  static const std::vector<spec::Spec> all = [] {
    std::vector<spec::Spec> v;
    for (const auto& e : embedded_specs()) {
      auto r = spec::load_spec_text(e.yaml, std::string(e.id) + ".yaml");
      if (!r.ok()) {
        std::fprintf(stderr, "fuzz: embedded spec %.*s does not load:\n", int(e.id.size()), e.id.data());
        for (const auto& d : r.diagnostics) std::fprintf(stderr, "  %s\n", d.str().c_str());
        std::abort();
      }
      v.push_back(std::move(*r.spec));
    }
    return v;
  }();
  return all;
}

const spec::Spec& spec_by_id(std::string_view id) {
  for (const auto& s : specs())
    if (s.device.id == id) return s;
  std::fprintf(stderr, "fuzz: no embedded spec '%.*s'\n", int(id.size()), id.data());
  std::abort();
}

void finding(const char* harness, const std::string& what) {
  std::fprintf(stderr, "\n==mbconform-fuzz== FINDING in %s: %s\n", harness, what.c_str());
  std::fflush(stderr);
  std::abort();
}

uint8_t default_slave(const spec::Spec& s) { return uint8_t(s.serial.slave_default.value_or(1)); }

namespace {
struct Pooled {
  std::unique_ptr<ref::Device> device;
  uint64_t writes_after_reset = 0;  // eeprom_writes() right after factory_reset
};
}  // namespace

ref::Device& fresh_device(size_t spec_index, uint8_t slave_id) {
  static std::vector<Pooled> pool(specs().size());
  Pooled& p = pool.at(spec_index);
  if (!p.device) {
    p.device = std::make_unique<ref::Device>(specs()[spec_index], slave_id);
    p.device->factory_reset();
    p.writes_after_reset = p.device->eeprom_writes();
  } else {
    // Only a stored write changes the stored image, and each one counts in
    // eeprom_writes(); restoring it is the factory reset's work, so skip that
    // (and comparing the images) when nothing was stored.
    if (p.device->eeprom_writes() != p.writes_after_reset) {
      p.device->factory_reset();
      p.writes_after_reset = p.device->eeprom_writes();
    }
  }
  p.device->power_cycle();
  p.device->set_slave_id(slave_id);
  return *p.device;
}

Image holding_image(const ref::Device& d) {
  static std::map<const spec::Spec*, std::vector<uint16_t>> addresses;
  auto& a = addresses[&d.spec()];
  if (a.empty())
    for (const auto& [addr, v] : d.holding_image()) a.push_back(addr);
  Image img(a.size());
  for (size_t i = 0; i < a.size(); ++i) img[i] = d.word(a[i]);
  return img;
}

std::string hex_or_silence(const std::optional<Bytes>& b) { return b ? to_hex(*b) : std::string("(silence)"); }

namespace {

bool exception_code_known(const spec::Spec& s, uint8_t code) {
  if (code >= 1 && code <= 4) return true;  // MBAP v1.1b3 §7, the codes every server may use
  for (const auto& e : s.profile.exception_codes)
    if (e.code == code) return true;
  for (const auto& [kind, p] : s.profile.exception_policy)
    if (p.kind == spec::PolicyEntry::Kind::exception && p.code == code) return true;
  return false;
}

std::string image_diff(const ref::Device& d, const Image& a, const Image& b) {
  std::vector<uint16_t> addrs;
  for (const auto& [addr, v] : d.holding_image()) addrs.push_back(addr);
  for (size_t i = 0; i < a.size() && i < b.size() && i < addrs.size(); ++i)
    if (a[i] != b[i]) {
      char buf[96];
      std::snprintf(buf, sizeof buf, "holding 0x%04X changed %04X -> %04X", addrs[i], a[i], b[i]);
      return buf;
    }
  return "holding image changed";
}

}  // namespace

void check_exchange(const char* harness, const ref::Device& device, std::span<const uint8_t> adu,
                    const std::optional<Bytes>& reply, const Image& before, const Image& after) {
  const spec::Spec& s = device.spec();
  auto ctx = [&](const std::string& what) {
    return s.device.id + " (slave " + std::to_string(device.slave_id()) + "): " + what + "\n  sent:  " +
           to_hex(adu) + "\n  reply: " + hex_or_silence(reply);
  };
  const bool framed = adu.size() >= 4 && adu.size() <= kMaxRtuAdu;  // MB-SL v1.02 §2.5.1.1
  const bool crc = framed && crc_ok(adu);
  const bool addressed = framed && adu[0] == device.slave_id();
  const bool broadcast = framed && s.serial.broadcast_address && adu[0] == *s.serial.broadcast_address;

  if (reply) {
    const Bytes& r = *reply;
    MBC_FUZZ_CHECK(r.size() >= 4 && r.size() <= kMaxRtuAdu, harness, ctx("reply length outside 4..256 (MB-SL v1.02 §2.5.1.1)"));
    MBC_FUZZ_CHECK(crc_ok(r), harness, ctx("reply CRC wrong"));
    MBC_FUZZ_CHECK(r[0] == device.slave_id(), harness, ctx("reply carries another slave id"));
    MBC_FUZZ_CHECK(addressed, harness, ctx("answered a frame not addressed to it (other slave id or broadcast, MB-SL v1.02 §2.1)"));
    std::span<const uint8_t> rpdu(r.data() + 1, r.size() - 3);
    if (!crc) {
      // Only a device whose manual says it answers CRC errors may (its policy).
      auto p = s.profile.policy(spec::Violation::crc_error);
      MBC_FUZZ_CHECK(p.kind == spec::PolicyEntry::Kind::exception, harness,
                     ctx("answered a frame with a bad CRC; the spec's crc_error policy is not an exception"));
      MBC_FUZZ_CHECK(rpdu.size() == 2 && rpdu[0] == uint8_t((adu[1] & 0x7F) | 0x80) && rpdu[1] == uint8_t(p.code), harness,
                     ctx("CRC-error reply is not the exception the spec's crc_error policy names"));
    } else {
      std::span<const uint8_t> qpdu(adu.data() + 1, adu.size() - 3);
      Judged j = judge_reply(qpdu, rpdu);
      std::string problems;
      for (const auto& p : j.problems) problems += "\n  judge: " + p;
      MBC_FUZZ_CHECK(j.ok(), harness, ctx("malformed reply" + problems));
      if (j.kind == Judged::Kind::exception)
        MBC_FUZZ_CHECK(exception_code_known(s, j.exception_code), harness,
                       ctx("exception code neither MBAP §7 nor the spec knows"));
    }
  }
  const bool rejected = reply && reply->size() == 5 && ((*reply)[1] & 0x80);
  if (!crc || (!addressed && !broadcast) || rejected)
    MBC_FUZZ_CHECK(before == after, harness,
                   ctx((rejected ? "an exception reply, yet " : "an invalid or foreign frame, yet ") + image_diff(device, before, after)));
}

}  // namespace mbc::fuzz
