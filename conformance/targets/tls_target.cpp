// mbtls://HOST:PORT?cert=FILE&key=FILE&ca=FILE[&unit=N&timeout=MS&silence=MS]:
// Modbus/TCP Security (MB-TCP-Security v2.1, "mbaps", port 802 by default).
// The MBAP ADU is carried unchanged inside TLS (§6), so this is the tcp://
// target exactly, reached through a TLS relay (reference/serve/tls.h): the
// relay's thread accepts the tcp:// target's connection on a loopback port of
// this process and carries it to HOST:PORT over TLS 1.2 or later, verifying
// the server's certificate against `ca` and its name against HOST, and
// presenting `cert`/`key`. Every reconnect is a new TLS connection.
//
// `clients=DIR` and `roles=FILE` are for the security checks
// (conformance/security/), not for the exchanges.
#include <fmt/core.h>
#include <openssl/ssl.h>
#include <unistd.h>

#include <stdexcept>

#include "serve/tls.h"
#include "targets/kinds.h"
#include "targets/live_link.h"

namespace mbc::conf {
namespace {

class TlsTarget final : public Target {
 public:
  explicit TlsTarget(const Uri& u) {
    uint16_t port = u.port ? u.port : tls::kMbapsPort;
    std::string base = fmt::format("mbtls://{}:{}", u.host, port);
    live::check_params(u, base, {"unit", "timeout", "silence", "cert", "key", "ca", "clients", "roles"});
    if (u.host.empty()) throw std::invalid_argument(fmt::format("target 'mbtls:{}': needs HOST[:PORT], e.g. mbtls://192.168.1.20:802?cert=...&key=...&ca=...", u.path));
    tls::Files f{u.param("cert").value_or(""), u.param("key").value_or(""), u.param("ca").value_or("")};
    if (f.ca.empty()) throw std::invalid_argument(fmt::format("target '{}': needs ca=FILE, the CA that signs the server's certificate", base));
    try {
      tls::check_files(f, "cert=", "key=", "ca=");
    } catch (const std::runtime_error& e) {
      throw std::invalid_argument(fmt::format("target '{}': {}", base, e.what()));
    }
    int timeout = live::int_param(u, base, "timeout", 1000, 1, 60000);
    // Refuse at once, with the handshake's reason, a server this client
    // cannot reach or does not trust (the relay would only close the socket).
    handshake_once(u.host, port, f, timeout, base);
    uint16_t local = relay_.listen_plain(u.host, port, tls::client_context(f), timeout);
    relay_.start();
    Uri inner;
    inner.scheme = "tcp";
    inner.host = "127.0.0.1";
    inner.port = local;
    for (const char* k : {"unit", "timeout", "silence"})
      if (auto v = u.param(k)) inner.query.emplace_back(k, *v);
    tcp_ = make_tcp_target(inner);
    info_ = tcp_->info();
    info_.kind = TargetKind::tls;
    info_.framing = framing_of(info_.kind);
    info_.live = is_live(info_.kind);
    info_.uri = fmt::format("{}?unit={}", base, info_.unit);
  }

  const TargetInfo& info() const override { return info_; }
  Reply transact(uint8_t unit, std::span<const uint8_t> pdu) override { return tcp_->transact(unit, pdu); }
  Reply send_raw(std::span<const uint8_t> bytes, std::optional<size_t> gap_after) override {
    return tcp_->send_raw(bytes, gap_after);
  }
  std::optional<std::chrono::microseconds> split_gap() const override { return tcp_->split_gap(); }
  void set_split_gap(std::chrono::microseconds g) override { tcp_->set_split_gap(g); }
  std::chrono::microseconds silence_window() const override { return tcp_->silence_window(); }
  void set_wait(Wait w) override { tcp_->set_wait(w); }
  uint64_t late_replies() const override { return tcp_->late_replies(); }
  bool reconnect() override { return tcp_->reconnect(); }
  void advance(std::chrono::microseconds dt) override { tcp_->advance(dt); }
  void power_cycle() override { tcp_->power_cycle(); }

 private:
  // With TLS 1.3 a client finishes its handshake before the server has
  // judged the client's certificate, so a refusal would only show as a
  // closed connection later. The opening handshake is therefore TLS 1.2 when
  // the server speaks it (there the server's verdict on the certificate
  // comes inside the handshake), and the default only when it does not.
  static void handshake_once(const std::string& host, uint16_t port, const tls::Files& f, int timeout,
                             const std::string& base) {
    tls::NoSigpipe no_sigpipe;
    std::string err = handshake(host, port, f, timeout, base, TLS1_2_VERSION);
    bool no_tls12 = err.find("protocol version") != std::string::npos || err.find("unsupported protocol") != std::string::npos ||
                    err.find("no protocols available") != std::string::npos;
    if (no_tls12) {
      // The server may still be closing the first connection (a one-shot
      // server resets the next one): a second connection that fails leaves
      // the first handshake's answer standing.
      try {
        err = handshake(host, port, f, timeout, base, 0);
      } catch (const std::runtime_error& e) {
        err += fmt::format("; a second handshake without the TLS 1.2 cap could not connect ({})", e.what());
      }
    }
    if (!err.empty()) throw std::runtime_error(fmt::format("target '{}': TLS handshake failed: {}", base, err));
  }

  // Empty on success, else why not.
  static std::string handshake(const std::string& host, uint16_t port, const tls::Files& f, int timeout,
                               const std::string& base, int max_version) {
    std::string why;
    int fd = tls::connect_tcp(host, port, timeout, why);
    if (fd < 0) throw std::runtime_error(fmt::format("target '{}': cannot connect: {}", base, why));
    tls::Ctx ctx = tls::client_context(f);
    if (max_version) SSL_CTX_set_max_proto_version(ctx.get(), max_version);
    SSL* ssl = SSL_new(ctx.get());
    SSL_set_fd(ssl, fd);
    tls::expect_host(ssl, host);
    bool ok = SSL_connect(ssl) == 1;
    std::string err = ok ? "" : tls::ssl_errors();
    long v = SSL_get_verify_result(ssl);
    if (ok) SSL_shutdown(ssl);  // close_notify
    SSL_free(ssl);
    ::close(fd);
    if (ok) return "";
    if (v != X509_V_OK) err += fmt::format(" ({})", X509_verify_cert_error_string(v));
    return err.empty() ? "connection closed" : err;
  }

  tls::Relay relay_;
  std::unique_ptr<Target> tcp_;  // destroyed before the relay
  TargetInfo info_;
};

}  // namespace

std::unique_ptr<Target> make_tls_target(const Uri& u) { return std::make_unique<TlsTarget>(u); }

}  // namespace mbc::conf
