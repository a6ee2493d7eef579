// Modbus/TCP Security (MB-TCP-Security v2.1, "mbaps", port 802): the TLS
// layer shared by `serve --tls`, the `mbtls://` target and the client
// scenario servers. TLS (OpenSSL) only: the MBAP ADU inside it is carried
// unchanged, so every Modbus decision stays where it is for plain TCP.
//
// The layer is a relay. Its thread owns every TLS connection and pumps the
// decrypted byte stream to and from a plain descriptor (a socketpair end that
// `serve` adopts as a Modbus TCP link, or a loopback connection): what runs
// above it is the Modbus/TCP code as it is, byte for byte.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

using SSL_CTX = struct ssl_ctx_st;
using SSL = struct ssl_st;
using X509 = struct x509_st;

namespace mbc::tls {

// The role extension of MB-TCP-Security v2.1 §8.3: OID 1.3.6.1.4.1.50316.802.1
// (the Modbus Organization's private enterprise number), an ASN.1 UTF8String.
inline constexpr const char* kRoleOid = "1.3.6.1.4.1.50316.802.1";
// The port IANA registered for mbaps.
inline constexpr uint16_t kMbapsPort = 802;

// PEM files of one side: its certificate chain, its private key, the CA(s)
// it trusts for the peer.
struct Files {
  std::string cert, key, ca;
};

// Checks the files before any socket is opened, so a mistake is one line:
// a certificate or CA that is missing or not PEM, a key that is missing,
// unreadable, readable by group or others, or does not match the
// certificate. Throws std::runtime_error("--key server.key: ...").
// `who` prefixes the file names ("--cert" style for serve, "cert=" for a URI).
void check_files(const Files& f, const std::string& cert_name, const std::string& key_name, const std::string& ca_name);

struct CtxDeleter {
  void operator()(SSL_CTX* c) const;
};
using Ctx = std::unique_ptr<SSL_CTX, CtxDeleter>;

// A server context: TLS 1.2 or later, the certificate and key, and a client
// certificate required and verified against `ca` (mutual authentication).
// The role check runs in the verification, so a certificate with no usable
// role is refused in the handshake when `require_role` is set, and a
// certificate with two roles always is.
Ctx server_context(const Files& f, bool require_role);
// A client context: TLS 1.2 or later, verifies the server against `ca`;
// sends `cert`/`key` when given (both or neither).
Ctx client_context(const Files& f);

// The role a certificate carries (MB-TCP-Security v2.1 §8.3).
struct Role {
  std::optional<std::string> name;  // set: exactly one role, a UTF8String
  std::string problem;              // set: the extension is there but unusable (two roles, wrong type)
};
Role role_of(X509* cert);

// What each role may do: function codes, and for the codes that address
// data, the address ranges. A YAML file:
//
//   mbconform_roles: 1
//   roles:
//     viewer:
//       - functions: [1, 2, 3, 4]
//     operator:
//       - functions: [1, 2, 3, 4]
//       - functions: [5, 6, 15, 16]
//         addresses: [0-99, 0x200-0x2FF]
//
// A rule without `addresses` allows its codes at every address. A request is
// allowed when one rule of its role allows its function code and every
// address it touches.
class Roles {
 public:
  // Throws std::runtime_error "FILE:LINE:COL: error: roles: what".
  static Roles load(const std::string& path);
  bool has(const std::string& role) const { return rules_.count(role) != 0; }
  // Empty when `pdu` is allowed for `role`; else why not, in words.
  std::string refusal(const std::string& role, std::span<const uint8_t> pdu) const;

  struct Rule {
    std::vector<uint8_t> functions;
    std::vector<std::pair<uint16_t, uint16_t>> addresses;  // inclusive; empty: any
  };
  std::map<std::string, std::vector<Rule>> rules_;
};

// The addresses a request touches: FC 01-06, 15, 16, 22, 23 (23: the union
// of its read and its write ranges, as two spans). Empty for codes that
// address no data, and for a PDU too short to say.
std::vector<std::pair<uint32_t, uint32_t>> addressed_ranges(std::span<const uint8_t> pdu);

// One accepted TLS connection, after its handshake.
struct Peer {
  std::string address;               // "127.0.0.1:40112"
  std::optional<std::string> role;   // from the client certificate
  std::string version;               // "TLSv1.3"
};

// The relay thread. Server side (`listen_tls`): accepts TLS on an address,
// runs the handshake (a client certificate required), then asks `inner` for
// the plain descriptor the connection's bytes go to and come from (-1 closes
// the connection). Client side (`listen_plain`): accepts plain connections on
// a loopback port, opens a TLS connection to `remote` for each, and relays.
// close_notify: a peer's close_notify half-closes the plain side; the plain
// side's end sends close_notify and closes. A FIN without close_notify ends
// that connection only. Two threads, each with one epoll set (no limit on
// descriptors): the door accepts and runs the handshakes, at a lower
// priority, and hands each connection whose handshake is done to the relay,
// which pumps the established connections' bytes (so a flood of handshakes
// never queues before a good client's bytes). A handshake has 5 s and at
// most 256 run at once (a quarter of the descriptors at most), 32 per peer
// address (past a cap the oldest makes room); the established connections
// fit the rest of RLIMIT_NOFILE (three descriptors each), the one unused the
// longest making room for a newcomer, and at the file limit a newcomer is
// refused cleanly (accepted and closed with a descriptor kept for it), never
// by a loop that spins.
class Relay {
 public:
  Relay();
  ~Relay();  // stops the thread, closes everything
  Relay(const Relay&) = delete;
  Relay& operator=(const Relay&) = delete;

  // Opens a TLS listener on HOST:PORT (port 0: the system picks one); the
  // bound address as "HOST:PORT". Throws std::runtime_error.
  std::string listen_tls(const std::string& host, uint16_t port, Ctx ctx,
                         std::function<int(const Peer&)> inner);
  // Opens a plain listener on 127.0.0.1 port 0 whose connections go out to
  // HOST:PORT over TLS, checking the server's certificate and host name;
  // returns the port. `timeout_ms` bounds connect and handshake. Only
  // connections from this process are relayed.
  uint16_t listen_plain(const std::string& host, uint16_t port, Ctx ctx, int timeout_ms);
  // Starts the thread (after the listeners are open).
  void start();
  // The last outgoing handshake's failure, in words (client side), empty when none.
  std::string last_error() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The server's certificate must name HOST (RFC 6125; an IP address as an
// iPAddress SAN); also sends HOST as SNI when it is a name.
void expect_host(SSL* ssl, const std::string& host);

// While alive, a write on a socket whose peer has gone (OpenSSL writes with
// write(2), not send(MSG_NOSIGNAL)) fails with EPIPE in this thread instead
// of killing the process with SIGPIPE; a SIGPIPE raised meanwhile is taken.
class NoSigpipe {
 public:
  NoSigpipe();
  ~NoSigpipe();
  NoSigpipe(const NoSigpipe&) = delete;
  NoSigpipe& operator=(const NoSigpipe&) = delete;

 private:
  unsigned char old_[128];  // the thread's signal mask (a sigset_t)
};

// One line about what OpenSSL's error queue holds, and clears it.
std::string ssl_errors();

// Connects to HOST:PORT within `timeout_ms` (blocking socket); -1 and `why`
// on failure.
int connect_tcp(const std::string& host, uint16_t port, int timeout_ms, std::string& why);

}  // namespace mbc::tls
