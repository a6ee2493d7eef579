#include "client/tls_front.h"

#include <openssl/ssl.h>

#include <filesystem>
#include <stdexcept>

#include <fmt/core.h>

namespace mbc::client {

TlsFront::TlsFront(const std::string& pki, const std::string& server, uint16_t plain_port, int max_version) : pki_(pki) {
  namespace fs = std::filesystem;
  tls::Files f{(fs::path(pki) / (server + ".crt")).string(), (fs::path(pki) / (server + ".key")).string(),
               (fs::path(pki) / "ca.crt").string()};
  tls::check_files(f, "--pki " + server + ".crt", "--pki " + server + ".key", "--pki ca.crt");
  tls::Ctx ctx = tls::server_context(f, false);
  if (max_version) {
    SSL_CTX_set_min_proto_version(ctx.get(), TLS1_VERSION);
    SSL_CTX_set_max_proto_version(ctx.get(), max_version);
    SSL_CTX_set_security_level(ctx.get(), 0);
    SSL_CTX_set_cipher_list(ctx.get(), "DEFAULT:@SECLEVEL=0");
  }
  relay_ = std::make_unique<tls::Relay>();
  auto count = handshakes_;
  std::string bound = relay_->listen_tls("127.0.0.1", 0, std::move(ctx), [count, plain_port](const tls::Peer&) {
    ++*count;
    if (!plain_port) return -1;
    std::string why;
    return tls::connect_tcp("127.0.0.1", plain_port, 2000, why);
  });
  port_ = uint16_t(std::stoi(bound.substr(bound.rfind(':') + 1)));
  relay_->start();
}

nlohmann::json TlsFront::connect_fields() const {
  namespace fs = std::filesystem;
  return {{"transport", "tls"},
          {"host", "127.0.0.1"},
          {"port", port_},
          {"ca", (fs::path(pki_) / "ca.crt").string()},
          {"cert", (fs::path(pki_) / "operator.crt").string()},
          {"key", (fs::path(pki_) / "operator.key").string()}};
}

}  // namespace mbc::client
