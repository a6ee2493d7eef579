#include "check/check.h"

#include <fmt/core.h>

#include <algorithm>

#include "modbus/mbap.h"
#include "modbus/rtu.h"

namespace mbc::conf::check {

std::vector<Reliance> all_relies(const Case& c) {
  std::vector<Reliance> out;
  auto add = [&](const std::vector<Reliance>& rs) {
    for (const auto& r : rs)
      if (std::none_of(out.begin(), out.end(), [&](const Reliance& o) { return o.fact == r.fact; })) out.push_back(r);
  };
  add(c.relies);
  for (const auto& st : c.steps) {
    add(st.expect.relies);
    for (const auto& alt : st.expect.either) add(alt.relies);
  }
  return out;
}

std::string describe(const Reliance& r) {
  using spec::Basis;
  const spec::FactBasis& b = r.basis;
  switch (b.basis) {
    case Basis::stated:
      return fmt::format("{}: stated{}", r.fact, b.section.empty() ? "" : " (§" + b.section + ")");
    case Basis::inferred:
      return fmt::format("{}: inferred ({}{})", r.fact, b.why, b.searched.empty() ? "" : "; searched " + b.searched);
    case Basis::observed:
      return fmt::format("{}: observed ({})", r.fact, b.why);
    case Basis::either: {
      std::string rs;
      for (const auto& x : b.readings) rs += (rs.empty() ? "" : " or ") + x;
      return fmt::format("{}: printed two ways, {}{}", r.fact, rs, b.erratum.empty() ? "" : " (erratum " + b.erratum + ")");
    }
  }
  return r.fact;
}

Step frame(Framing framing, uint8_t unit, Bytes pdu, Expect expect, std::string note) {
  Step s;
  s.framing = framing;
  s.unit = unit;
  s.pdu = std::move(pdu);
  s.expect = std::move(expect);
  s.note = std::move(note);
  return s;
}

Step raw_rtu(Bytes adu, std::optional<size_t> gap, Expect expect, std::string note) {
  Step s;
  s.kind = Step::Kind::raw;
  s.framing = &mbc::kRtu;
  s.bytes = std::move(adu);
  s.gap = gap;
  s.expect = std::move(expect);
  s.note = std::move(note);
  return s;
}

Step raw_mbap(Bytes adu, Expect expect, std::string note) {
  Step s = raw_rtu(std::move(adu), std::nullopt, std::move(expect), std::move(note));
  s.framing = &mbc::kTcp;
  return s;
}

Step advance(uint64_t us) {
  Step s;
  s.kind = Step::Kind::advance;
  s.us = us;
  return s;
}

Step power_cycle() {
  Step s;
  s.kind = Step::Kind::power_cycle;
  return s;
}

Bytes wire_bytes(const Step& s, Framing framing) {
  if (s.kind == Step::Kind::raw) return s.bytes;
  if (s.kind != Step::Kind::frame) return {};
  return framing == &mbc::kRtu ? rtu_frame(s.unit, s.pdu) : mbap_frame(s.tid.value_or(0), s.unit, s.pdu);
}

bool is_broadcast_write(const Step& st) {
  if (st.kind == Step::Kind::frame) return st.unit == 0 && !st.pdu.empty() && (st.pdu[0] < 1 || st.pdu[0] > 4);
  if (st.kind == Step::Kind::raw && st.framing == &mbc::kRtu)
    return st.bytes.size() >= 2 && st.bytes[0] == 0 && (st.bytes[1] < 1 || st.bytes[1] > 4);
  if (st.kind == Step::Kind::raw)
    return st.bytes.size() > kMbapHeader && st.bytes[6] == 0 && (st.bytes[7] < 1 || st.bytes[7] > 4);
  return false;
}

std::optional<Step> fill_words(const Step& st, const std::optional<Bytes>& reply) {
  if (st.words_from < 0) return st;
  if (!reply || reply->size() < 2 || (*reply)[0] != 3 || reply->size() != size_t(2 + (*reply)[1])) return std::nullopt;
  Step out = st;
  size_t words = (*reply)[1] / 2;
  // FC 06: address, value; FC 16: address, quantity, byte count, values.
  size_t at = st.pdu.size() >= 1 && st.pdu[0] == 6 ? 3 : 6;
  if (st.pdu.size() != at + 2 * words) return std::nullopt;
  std::copy(reply->begin() + 2, reply->end(), out.pdu.begin() + ptrdiff_t(at));
  std::string vals;
  for (size_t i = 0; i < words; ++i) vals += fmt::format("{}{:02X}{:02X}", i ? " " : "", (*reply)[2 + 2 * i], (*reply)[3 + 2 * i]);
  out.note += fmt::format(" [{}]", vals);
  return out;
}

}  // namespace mbc::conf::check
