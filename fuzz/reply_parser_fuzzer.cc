// The master-side reply parser the runner judges targets with
// (modbus/judge.h: judge_reply, describe_pdu), against a small
// independent oracle written here from MBAP v1.1b3 §6/§7: the two must agree
// on whether a reply is well formed, and a well-formed read must decode to
// exactly the requested number of registers or bits, with the values sent.
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_support.h"
#include "modbus/bytes.h"
#include "modbus/judge.h"
#include "modbus/limits.h"

namespace {
using namespace mbc;
constexpr const char* kHarness = "reply_parser_fuzzer";

// Well formed per MBAP v1.1b3, for the function codes whose reply shape the
// standard fixes; nullopt where the shape is device specific (7, 8, 17, 43...).
std::optional<bool> oracle(std::span<const uint8_t> req, std::span<const uint8_t> rep) {
  if (rep.empty()) return false;
  if (rep.size() > kMaxPdu) return false;  // §4.1
  uint8_t fc = req.empty() ? 0 : req[0];
  if (rep[0] == uint8_t(fc | 0x80)) return rep.size() == 2;  // §7: function | 0x80, exception code
  if (rep[0] != fc) return false;
  auto echo = [&](size_t n) { return rep.size() == n && req.size() >= n && std::equal(rep.begin(), rep.end(), req.begin()); };
  switch (fc) {
    case 1:
    case 2: {  // §6.1/6.2: byte count N = ceil(quantity / 8), unused high bits zero
      if (req.size() < 5) return false;
      size_t q = be16(req, 3), n = (q + 7) / 8;
      if (rep.size() != 2 + n || rep[1] != n) return false;
      return q % 8 == 0 || n == 0 || (rep[1 + n] >> (q % 8)) == 0;
    }
    case 3:
    case 4:
    case 23: {  // §6.3/6.4/6.17: byte count 2 x quantity
      if (req.size() < 5) return false;
      size_t q = be16(req, 3);
      return rep.size() == 2 + 2 * q && rep[1] == 2 * q;
    }
    case 5:
    case 6:
    case 15:
    case 16: return echo(5);  // §6.5/6.6: echo; §6.11/6.12: address and quantity
    case 22: return echo(7);  // §6.16: echo
    default: return std::nullopt;
  }
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  size_t n = std::min<size_t>(data[0], size - 1);
  std::span<const uint8_t> req(data + 1, n), rep(data + 1 + n, size - 1 - n);
  Judged j = judge_reply(req, rep);
  auto ctx = [&](const std::string& what) {
    std::string s = what + "\n  request: " + to_hex(req) + "\n  reply:   " + to_hex(rep);
    for (const auto& p : j.problems) s += "\n  judge: " + p;
    return s;
  };
  MBC_FUZZ_CHECK(j.ok() == (j.problems.empty() && j.kind != Judged::Kind::malformed), kHarness, ctx("ok() inconsistent"));
  if (auto want = oracle(req, rep)) {
    MBC_FUZZ_CHECK(j.ok() == *want, kHarness,
                   ctx(*want ? "judge rejects a reply MBAP v1.1b3 calls well formed" : "judge accepts a malformed reply"));
  }
  if (j.ok() && j.kind == Judged::Kind::normal && req.size() >= 5) {
    uint8_t fc = req[0];
    size_t q = be16(req, 3);
    if (fc == 3 || fc == 4 || fc == 23) {
      MBC_FUZZ_CHECK(j.registers.size() == q, kHarness, ctx("decoded register count != quantity"));
      for (size_t i = 0; i < q; ++i)
        MBC_FUZZ_CHECK(j.registers[i] == be16(rep, 2 + 2 * i), kHarness, ctx("register " + std::to_string(i) + " decoded wrong"));
    }
    if (fc == 1 || fc == 2) {
      MBC_FUZZ_CHECK(j.bits.size() == q, kHarness, ctx("decoded bit count != quantity"));
      for (size_t i = 0; i < q; ++i)
        MBC_FUZZ_CHECK(j.bits[i] == bool(rep[2 + i / 8] >> (i % 8) & 1), kHarness, ctx("bit " + std::to_string(i) + " decoded wrong"));
    }
  }
  if (j.kind == Judged::Kind::exception && j.ok())
    MBC_FUZZ_CHECK(j.exception_code == rep[1], kHarness, ctx("exception code not the reply's second byte"));
  MBC_FUZZ_CHECK(!describe_pdu(rep, false).empty() && !describe_pdu(req, true).empty(), kHarness,
                 ctx("describe_pdu printed nothing"));
  return 0;
}
