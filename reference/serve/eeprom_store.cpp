#include "serve/eeprom_store.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include <fmt/core.h>
#include <nlohmann/json.hpp>

namespace mbc::serve {

namespace fs = std::filesystem;

std::string eeprom_file(const std::string& dir, const std::string& device_id, uint8_t slave) {
  return (fs::path(dir) / fmt::format("{}@{}.json", device_id, slave)).string();
}

std::optional<StoredImage> load_eeprom(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return std::nullopt;
  std::ifstream in(path);
  try {
    nlohmann::json j = nlohmann::json::parse(in);
    StoredImage image;
    for (const auto& [addr, value] : j.at("stored").items()) {
      unsigned long a = std::stoul(addr, nullptr, 0);
      auto v = value.get<int64_t>();
      if (a > 0xFFFF || v < 0 || v > 0xFFFF) throw std::out_of_range(addr);
      image[uint16_t(a)] = uint16_t(v);
    }
    return image;
  } catch (const std::exception& e) {
    throw std::runtime_error(fmt::format("{}: not an EEPROM image: {}", path, e.what()));
  }
}

void save_eeprom(const std::string& path, const std::string& device_id, uint8_t slave, const StoredImage& image) {
  nlohmann::ordered_json j{{"device", device_id}, {"slave", slave}, {"stored", nlohmann::ordered_json::object()}};
  for (const auto& [a, v] : image) j["stored"][fmt::format("0x{:04X}", a)] = v;
  std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    out << j.dump(2) << "\n";
    if (!out) throw std::runtime_error("cannot write " + tmp);
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) throw std::runtime_error(fmt::format("cannot rename {} to {}: {}", tmp, path, ec.message()));
}

}  // namespace mbc::serve
