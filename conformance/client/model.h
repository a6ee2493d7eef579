// The scenario server's data: what every address holds, so a correct reply
// and the values an adapter must report follow from the request alone. The
// "other" values are what a faulty reply carries (a wrong transaction id, a
// late reply): a master that reports them took the wrong frame.
#pragma once

#include <cstdint>
#include <string>

#include <nlohmann/json.hpp>

#include "modbus/bytes.h"
#include "modbus/pdu.h"

namespace mbc::client::model {

inline constexpr uint8_t kUnit = 17;  // every scenario addresses unit 17 (broadcast: 0)

// Holding register a holds 0x1000 + a, input register a 0x2000 + a; coil a is
// on when a % 3 == 0, discrete input a when a is odd.
uint16_t holding(uint16_t a, bool other = false);
uint16_t input(uint16_t a, bool other = false);
bool coil(uint16_t a, bool other = false);
bool discrete(uint16_t a, bool other = false);

// FC 43 / MEI 14, read device id code 1: the basic objects (MBAP v1.1b3 §6.21).
inline const char* const kVendor = "mbconform";
inline const char* const kProduct = "scenario-server";
inline const char* const kRevision = "1.0";

// The function code of a protocol op ("read_holding_registers" -> 0x03); 0 when unknown.
uint8_t function_of(const std::string& op);

// The PDU a correct master puts on the wire for `op` (MBAP v1.1b3 §6).
Bytes expected_request(const nlohmann::json& op);

// The correct reply PDU to `r`, from the model (`other`: the other values).
Bytes reply_to(const Request& r, bool other = false);

// The values a correct adapter reports for `op` answered from the model.
nlohmann::json expected_values(const nlohmann::json& op, bool other = false);

}  // namespace mbc::client::model
