// Modbus/TCP Security checks (MB-TCP-Security v2.1, "mbaps"): what a secure
// server does in and around the TLS handshake, where the cases of cases/
// (frames inside the connection) cannot look. Each check opens its own TLS
// connections with OpenSSL, with the settings the check needs (an old TLS
// version, no certificate, an untrusted or expired one, two roles), and
// becomes one CaseResult in the run's report beside the standard cases, which
// run over the same TLS target unchanged (the MBAP ADU is carried as is).
//
// What the specification requires of a server is MUST: mutual authentication
// (the server asks for the client's certificate, refuses a client without
// one and one it cannot verify), TLS 1.2 or later, the MBAP ADU carried
// unchanged inside TLS, and the role extension as defined (one role, a
// UTF8String). What it leaves to the server (no role, resumption,
// close_notify, how a role is authorized) stays OBSERVED. Each check's
// message starts with one word a CI gate can match: "refused", "accepted",
// "requested", "not-requested", "mbap", "bare-pdu", "not-mbap", "sent",
// "not-sent", "resumed", "not-resumed", "answered", "closed", "silent"; a
// MUST is met by one word only (README.md, "The checks").
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

// Each check as --list and --plan show it.
struct CheckListing {
  std::string id, clause, title, requirement;
  Level level = Level::observed;
};
std::vector<CheckListing> check_listing();

// Runs every check; ids are "<device>/security/<what>".
std::vector<CaseResult> check_server(const ServerUnderTest& s, const std::string& device_id);

}  // namespace mbc::conf::security
