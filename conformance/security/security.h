// Modbus/TCP Security checks (MB-TCP-Security v2.1, "mbaps"): what a secure
// server does in and around the TLS handshake, where the cases of cases/
// (frames inside the connection) cannot look. Each check opens its own TLS
// connections with OpenSSL, with the settings the check needs (an old TLS
// version, no certificate, an untrusted or expired one, two roles), and
// becomes one CaseResult in the run's report beside the standard cases, which
// run over the same TLS target unchanged (the MBAP ADU is carried as is).
//
// The text of the specification is not among this project's sources, so no
// check can quote its sentence: every check is OBSERVED (recorded, never
// failed) and names the clause and, where known, the requirement id. Each
// check's message starts with one word a CI gate can match: "refused",
// "accepted", "requested", "not-requested", "sent", "not-sent", "resumed",
// "not-resumed", "answered", "closed", "silent".
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "report/result.h"
#include "serve/tls.h"

namespace mbc::conf::security {

struct ServerUnderTest {
  std::string uri;          // as given
  std::string host;
  uint16_t port = tls::kMbapsPort;
  tls::Files files;         // the client's own certificate, key and the CA of the server
  std::string clients_dir;  // clients=DIR: expired.crt, two-roles.crt, ... (absent: those checks skip)
  std::string roles_file;   // roles=FILE: what the server's roles allow (absent: the authorization check skips)
  uint8_t unit = 1;
  int timeout_ms = 1000;
};

// From an mbtls:// URI (targets/tls_target.cpp); throws std::invalid_argument.
ServerUnderTest from_uri(const std::string& uri);

// The checks' ids under "<device>/security/" (for --filter and --list).
std::vector<std::string> check_names();

// Each check as --list and --plan show it (every one OBSERVED: no sentence
// of the specification is in this project's sources).
struct CheckListing {
  std::string id, clause, title, requirement;
};
std::vector<CheckListing> check_listing();

// Runs every check; ids are "<device>/security/<what>".
std::vector<CaseResult> check_server(const ServerUnderTest& s, const std::string& device_id);

}  // namespace mbc::conf::security
