// `mbconform client --transport tls --pki DIR`: the scenario server over
// Modbus/TCP Security. A TLS relay (reference/serve/tls.h) listens on a
// loopback port, requires the adapter's client certificate, and carries each
// connection to the plain scenario server unchanged (the MBAP ADU inside TLS,
// MB-TCP-Security v2.1 §6). DIR holds make_pki.sh's files: ca.crt,
// server.crt/.key (the server's), operator.crt/.key (what the adapter
// presents); server-untrusted, server-wrong-host, server-expired for the
// client-side checks.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "serve/tls.h"

namespace mbc::client {

class TlsFront {
 public:
  // `server`: the certificate's base name in `pki` ("server"); `plain_port`:
  // where connections go (0: nowhere, the connection is closed after its
  // handshake); `max_version`: 0, or TLS1_1_VERSION for a server that speaks
  // only old TLS. Throws std::runtime_error (one line).
  TlsFront(const std::string& pki, const std::string& server, uint16_t plain_port, int max_version = 0);
  uint16_t port() const { return port_; }
  // The adapter's connect fields: transport tls, host, port, ca, cert, key.
  nlohmann::json connect_fields() const;
  // Handshakes completed: the client accepted this server (and sent a certificate it trusts).
  int handshakes() const { return handshakes_->load(); }

 private:
  std::string pki_;
  uint16_t port_ = 0;
  std::shared_ptr<std::atomic<int>> handshakes_ = std::make_shared<std::atomic<int>>(0);
  std::unique_ptr<tls::Relay> relay_;
};

}  // namespace mbc::client
