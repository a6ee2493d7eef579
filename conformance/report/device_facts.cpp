// The device's own facts for the report's summary, from the spec the run
// used: its title, the identification objects it states (FC 43), the
// registers whose names say they hold the firmware, its line settings, a
// name for every register and the text of every erratum.
#include <fmt/core.h>
#include <fmt/format.h>

#include <algorithm>
#include <cctype>

#include "report/report.h"

namespace mbc::conf {
namespace {

std::string lower(std::string s) {
  for (auto& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// A register that holds the firmware's version, by its name in the manual.
bool names_firmware(const spec::Register& r) {
  std::string en = lower(r.name.en);
  for (const char* w : {"firmware", "software version", "version"})
    if (en.find(w) != std::string::npos) return true;
  for (const char* w : {"软件版本", "固件", "版本"})
    if (r.name.zh.find(w) != std::string::npos) return true;
  return false;
}

}  // namespace

void describe_device(DeviceRun& d, const spec::Spec& s) {
  DeviceFacts& f = d.facts;
  // A vendor the manual does not print ("(not printed in the manual)") is
  // left out; the model names come first, then the manual's title.
  bool vendor = !s.device.vendor.empty() && s.device.vendor.front() != '(';
  f.title = vendor ? s.device.vendor + " " + s.device.title : s.device.title;
  if (!s.device.models.empty()) {
    std::string models = fmt::format("{}", fmt::join(s.device.models, ", "));
    f.title = f.title.find(models) == 0 || (vendor && f.title.find(models) == s.device.vendor.size() + 1)
                  ? f.title
                  : fmt::format("{} ({})", f.title, models);
  }
  const auto& id = s.device.identification;
  if (!id.vendor_name.empty()) f.identity.emplace_back("VendorName", id.vendor_name);
  if (!id.product_code.empty()) f.identity.emplace_back("ProductCode", id.product_code);
  if (!id.revision.empty()) f.identity.emplace_back("MajorMinorRevision", id.revision);
  std::string line;
  if (s.serial.baud_default) line += fmt::format("{} baud", *s.serial.baud_default);
  else if (!s.serial.baud_rates.empty()) line += fmt::format("{} baud", fmt::join(s.serial.baud_rates, "/"));
  if (s.serial.frame_default) line += (line.empty() ? "" : " ") + *s.serial.frame_default;
  else if (!s.serial.frame_formats.empty()) line += (line.empty() ? "" : " ") + fmt::format("{}", fmt::join(s.serial.frame_formats, "/"));
  if (!line.empty()) line += " (the manual's default)";
  if (s.serial.slave_default) line += fmt::format("{}slave id {} by default", line.empty() ? "" : ", ", *s.serial.slave_default);
  // Line settings are a serial line's: a Modbus TCP or TLS target has none.
  bool tcp = d.target_uri.rfind("tcp://", 0) == 0 || d.target_uri.rfind("mbtls://", 0) == 0;
  f.line = tcp ? "" : line;
  // Holding registers first: a case's register address is a holding address
  // unless the device maps only another table there.
  for (auto t : {spec::Table::holding, spec::Table::input, spec::Table::coil, spec::Table::discrete_input})
    for (const auto& r : s.registers) {
      if (r.table != t) continue;
      std::string name = !r.name.en.empty() ? r.name.en : !r.name.zh.empty() ? r.name.zh : r.key;
      for (uint32_t a = r.address; a <= r.last_address(); ++a) f.register_names.emplace(uint16_t(a), name);
      if (t == spec::Table::holding && names_firmware(r) && r.access != spec::Access::wo) f.firmware_registers.push_back(r.address);
    }
  for (const auto& e : s.errata) {
    std::string text = fmt::format("§{}: printed {}; read as {}", e.section, e.printed, e.resolved);
    if (!e.why.empty()) text += " (" + e.why + ")";
    f.errata[e.id] = text;
  }
}

}  // namespace mbc::conf
