// The RTU frame decoding shared by the reference side and the master side:
// CRC-16 (MB-SL v1.02 §2.5.1.2), hex frames, where a request ends on a byte
// stream (modbus/rtu.h), the MBAP header, and the master's
// reply decoder (decode_rtu_reply) followed by its judge; the PDU parsers
// (modbus/pdu.h) in both directions.
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_support.h"
#include "modbus/crc16.h"
#include "modbus/function_codes.h"
#include "modbus/hex.h"
#include "modbus/judge.h"
#include "modbus/mbap.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "targets/kinds.h"

namespace {
constexpr const char* kHarness = "rtu_frame_fuzzer";
using namespace mbc;

void check(bool cond, const std::string& what, std::span<const uint8_t> in) {
  MBC_FUZZ_CHECK(cond, kHarness, what + "\n  input: " + to_hex(in));
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::span<const uint8_t> in(data, size);

  // CRC: a frame with its CRC appended checks; flipping any bit breaks it.
  Bytes framed(in.begin(), in.end());
  append_crc(framed);
  // (crc_ok wants at least one byte before the CRC: two bytes are no frame.)
  if (size > 0) {
    check(crc_ok(framed), "crc_ok rejects a frame carrying its own CRC", in);
    framed[size / 2] ^= uint8_t(1u << (size % 8));
    check(!crc_ok(framed), "crc_ok accepts a frame with one bit flipped (CRC-16 detects every 1-bit error)", in);
  }

  // Hex: what to_hex prints, parse_hex_strict reads back exactly; the lenient
  // parser on arbitrary text never crashes and round-trips what it accepts.
  // (No bytes print as "", which the strict format, a frame, does not accept.)
  std::string hex = to_hex(in);
  auto back = parse_hex_strict(hex);
  if (size > 0) check(back && *back == Bytes(in.begin(), in.end()), "parse_hex_strict(to_hex(x)) != x", in);
  std::string_view text(reinterpret_cast<const char*>(data), size);
  if (auto lenient = parse_hex(text)) {
    auto again = parse_hex(to_hex(*lenient));
    check(again && *again == *lenient, "parse_hex does not round-trip what it accepted", in);
  }

  // Stream framing: once a prefix fixes the request length, longer prefixes
  // (up to that length) agree; a length is never shorter than the bytes it was
  // decided from, and never shorter than slave + FC + CRC.
  std::optional<size_t> decided;
  size_t decided_at = 0;
  for (size_t k = 0; k <= size && k <= 300; ++k) {
    auto n = rtu_adu_length(in.first(k), Direction::request);
    if (decided && k <= *decided) {
      check(n == decided, "rtu_adu_length changes its mind after " + std::to_string(decided_at) + " bytes", in);
    } else if (n && !decided) {
      decided = n;
      decided_at = k;
      check(*n >= 4 && *n >= k, "rtu_adu_length " + std::to_string(*n) + " from " + std::to_string(k) + " bytes", in);
    }
  }

  // MBAP header: parse and re-emit keep transaction, protocol and unit.
  if (auto h = parse_mbap(in)) {
    size_t pdu_len = size - kMbapHeader;
    Bytes out = mbap_reply(*h, in.subspan(kMbapHeader));
    auto h2 = parse_mbap(out);
    check(h2 && h2->transaction == h->transaction && h2->protocol == h->protocol && h2->unit == h->unit &&
              h2->length == uint16_t(1 + pdu_len) && out.size() == size,
          "mbap_reply(parse_mbap(x)) does not keep the header", in);
  }

  // The master's decoder: a PDU comes out only of a frame that is valid for
  // the slave asked; otherwise a reason is given.
  for (uint8_t slave : {uint8_t(size ? data[0] : 1), uint8_t(size ? data[0] ^ 1 : 2)}) {
    conf::Reply r;
    r.frame.assign(in.begin(), in.end());
    conf::decode_rtu_reply(r, slave);
    bool valid = size >= 4 && size <= 256 && crc_ok(in) && data[0] == slave;
    if (size == 0) {
      check(!r.pdu && r.framing_error.empty(), "silence decoded as a frame or an error", in);
      continue;
    }
    check(valid == r.pdu.has_value(), valid ? "valid frame rejected: " + r.framing_error : "invalid frame accepted", in);
    check(valid == r.framing_error.empty(), "framing_error set together with a pdu, or neither", in);
    if (r.pdu) {
      check(r.pdu->size() == size - 3 && std::equal(r.pdu->begin(), r.pdu->end(), data + 1), "pdu is not the frame's middle", in);
      // The judge on the decoded PDU, against a request with the same FC.
      Bytes req(r.pdu->begin(), r.pdu->begin() + std::min<size_t>(r.pdu->size(), 5));
      if (!req.empty()) req[0] &= 0x7F;
      Judged j = judge_reply(req, *r.pdu);
      check(j.ok() == (j.problems.empty() && j.kind != Judged::Kind::malformed), "Judged::ok inconsistent", in);
      (void)describe_pdu(*r.pdu, false);
    }
  }
  // And the encoder feeding the decoder gives the PDU back (MB-SL §2.5.1).
  if (size >= 2 && size <= 254) {
    conf::Reply r;
    r.frame = rtu_frame(data[0], in.subspan(1));
    conf::decode_rtu_reply(r, data[0]);
    check(r.pdu && *r.pdu == Bytes(in.begin() + 1, in.end()), "decode_rtu_reply(rtu_frame(s, pdu)) != pdu", in);
  }

  // PDU parsers: an input decodes or names why not, never both; what decodes
  // builds back to the same bytes (requests: when no rule is broken, FC 15's
  // unused padding bits aside); rtu_unframe agrees with crc_ok.
  ParsedRequest pq = parse_request(in);
  check(pq.request.has_value() != !pq.error.empty(), "parse_request: a request and an error, or neither", in);
  if (pq.ok() && in[0] != fc::write_multiple_coils)
    check(build_request(*pq.request) == Bytes(in.begin(), in.end()), "build_request(parse_request(x)) != x", in);
  ParsedReply pr = parse_reply(in);
  check(pr.reply.has_value() != !pr.error.empty(), "parse_reply: a reply and an error, or neither", in);
  if (pr.reply) check(build_reply(*pr.reply) == Bytes(in.begin(), in.end()), "build_reply(parse_reply(x)) != x", in);
  if (size >= 4 && size <= kMaxRtuAdu) check(rtu_unframe(in).ok() == crc_ok(in), "rtu_unframe disagrees with crc_ok", in);
  return 0;
}
