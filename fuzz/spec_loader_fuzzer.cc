// The spec loader (YAML -> JSON with locations -> JSON Schema -> structs ->
// semantic rules) on arbitrary bytes: it must never crash or hang, and it
// reports every rejection as a diagnostic with a location inside the text:
// one about a library profile's entry stands at the spec's own control: line.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "fuzz_support.h"
#include "loader.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace mbc;
  constexpr const char* kHarness = "spec_loader_fuzzer";
  std::string_view text(reinterpret_cast<const char*>(data), size);
  constexpr const char* kFile = "fuzz-input.yaml";
  spec::LoadResult r = spec::load_spec_text(text, kFile);
  if (!r.ok()) {
    MBC_FUZZ_CHECK(!r.diagnostics.empty(), kHarness, "rejected with no diagnostic");
    // Lines are 1-based and inside the text (0 = no location).
    size_t lines = 1;
    for (char c : text) lines += c == '\n';
    for (const auto& d : r.diagnostics) {
      MBC_FUZZ_CHECK(d.file == kFile && d.line >= 0 && size_t(d.line) <= lines + 1 && d.col >= 0, kHarness,
                     "diagnostic outside the text: " + d.str());
      MBC_FUZZ_CHECK(!d.rule.empty() && !d.message.empty(), kHarness, "diagnostic without rule or message: " + d.str());
    }
  } else {
    // An accepted spec is internally consistent: registers sorted by (table, address).
    const auto& regs = r.spec->registers;
    for (size_t i = 1; i < regs.size(); ++i)
      MBC_FUZZ_CHECK(std::pair(int(regs[i - 1].table), regs[i - 1].address) <= std::pair(int(regs[i].table), regs[i].address),
                     kHarness, "accepted spec's registers are not sorted by (table, address)");
  }
  return 0;
}
