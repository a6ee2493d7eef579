// A device's EEPROM/flash image kept across `serve` restarts:
// DIR/<id>@<slave>.json = {"device": id, "slave": n, "stored": {"0x0016": 1, ...}}.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>

namespace mbc::serve {

using StoredImage = std::map<uint16_t, uint16_t>;

std::string eeprom_file(const std::string& dir, const std::string& device_id, uint8_t slave);

// nullopt when the file does not exist (a device fresh from the factory);
// throws std::runtime_error when it exists but cannot be read.
std::optional<StoredImage> load_eeprom(const std::string& path);

// Writes atomically (temporary file, then rename); throws on failure.
void save_eeprom(const std::string& path, const std::string& device_id, uint8_t slave, const StoredImage& image);

}  // namespace mbc::serve
