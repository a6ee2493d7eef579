#include "security/security.h"

#include <fmt/core.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/ssl.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>

#include "modbus/mbap.h"
#include "targets/target.h"

namespace mbc::conf::security {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// The request every check sends once connected: FC 03, one register at 0
// (MBAP v1.1b3 §6.3); any reply, normal or exception, shows the connection
// was let in.
const Bytes kProbePdu{0x03, 0x00, 0x00, 0x00, 0x01};
constexpr uint16_t kProbeTid = 0x5EC1;
// The sentence a server that drops the MBAP header fails with.
constexpr const char* kNoMbap = "PDU without the MBAP header that Modbus/TCP Security carries inside TLS";

struct Client {
  std::string cert, key;        // empty: no client certificate
  int min_version = TLS1_VERSION;
  int max_version = 0;          // 0: the highest OpenSSL has
  SSL_SESSION* session = nullptr;  // offered for resumption
  bool request = true;          // send kProbePdu after the handshake
  std::optional<Bytes> pdu;     // instead of kProbePdu
  std::optional<Bytes> raw;     // sent as is, without an MBAP header (whatever comes back is raw_reply)
  bool close = false;           // send close_notify after the reply and wait for the server's
};

Client with_cert(const std::string& cert, const std::string& key) {
  Client c;
  c.cert = cert;
  c.key = key;
  return c;
}

struct Attempt {
  bool tcp = false;
  bool handshake = false;
  bool cert_requested = false;  // a CertificateRequest came
  std::string version;
  std::string error;            // the handshake's failure
  std::optional<int> alert;     // an alert the server sent (description)
  enum class After { none, answered, closed, silent } after = After::none;
  Bytes reply;                  // the PDU answered
  Bytes raw_reply;              // every byte that came back (also when it was no MBAP ADU)
  bool resumed = false;
  long peer_version = -1;       // X509_get_version of the server's certificate (2: X.509 v3), -1: none seen
  bool close_notify_back = false;  // the server answered our close_notify with its own
  std::string close_text;
  std::shared_ptr<SSL_SESSION> session;  // the session, for a resumption
};

struct Seen {
  bool cert_requested = false;
  std::optional<int> alert;
};

void on_message(int write_p, int, int content_type, const void* buf, size_t len, SSL*, void* arg) {
  auto* seen = static_cast<Seen*>(arg);
  const auto* b = static_cast<const unsigned char*>(buf);
  if (write_p || len < 1) return;
  if (content_type == SSL3_RT_HANDSHAKE && b[0] == SSL3_MT_CERTIFICATE_REQUEST) seen->cert_requested = true;
  if (content_type == SSL3_RT_ALERT && len >= 2 && !seen->alert) seen->alert = b[1];
}

// One connection as `c` says. The server is not verified here: the checks
// are about what the server accepts, not whether this client trusts it.
Attempt attempt(const ServerUnderTest& s, const Client& c) {
  tls::NoSigpipe no_sigpipe;  // a server that refused us may have closed already
  Attempt a;
  std::string why;
  int fd = tls::connect_tcp(s.host, s.port, s.timeout_ms, why);
  if (fd < 0) {
    a.error = "cannot connect: " + why;
    return a;
  }
  a.tcp = true;
  tls::Ctx ctx(SSL_CTX_new(TLS_client_method()));
  SSL_CTX_set_min_proto_version(ctx.get(), c.min_version);
  if (c.max_version) SSL_CTX_set_max_proto_version(ctx.get(), c.max_version);
  // OpenSSL 3 refuses TLS 1.0/1.1 at its default security level: a client
  // that offers them must lower it, or the refusal would be this side's.
  if (c.max_version && c.max_version < TLS1_2_VERSION) {
    SSL_CTX_set_security_level(ctx.get(), 0);
    SSL_CTX_set_cipher_list(ctx.get(), "DEFAULT:@SECLEVEL=0");
  }
  SSL_CTX_set_verify(ctx.get(), SSL_VERIFY_NONE, nullptr);
  // No client session cache: freeing the context would flush it, and a
  // session flushed from a cache is marked not resumable (the session kept
  // for the resumption check outlives this context).
  if (!c.cert.empty()) {
    if (SSL_CTX_use_certificate_chain_file(ctx.get(), c.cert.c_str()) != 1 ||
        SSL_CTX_use_PrivateKey_file(ctx.get(), c.key.c_str(), SSL_FILETYPE_PEM) != 1) {
      a.error = "client certificate " + c.cert + ": " + tls::ssl_errors();
      ::close(fd);
      return a;
    }
  }
  Seen seen;
  SSL_CTX_set_msg_callback(ctx.get(), on_message);
  SSL_CTX_set_msg_callback_arg(ctx.get(), &seen);
  SSL* ssl = SSL_new(ctx.get());
  SSL_set_fd(ssl, fd);
  tls::expect_host(ssl, s.host);  // SNI only; verification is off
  if (c.session) SSL_set_session(ssl, c.session);
  auto finish = [&] {
    a.cert_requested = seen.cert_requested;
    a.alert = seen.alert;
    SSL_free(ssl);
    ::close(fd);
    ERR_clear_error();
    return a;
  };
  if (SSL_connect(ssl) != 1) {
    a.error = tls::ssl_errors();
    if (a.error.empty()) a.error = "the server closed the connection";
    return finish();
  }
  a.handshake = true;
  a.version = SSL_get_version(ssl);
  a.resumed = SSL_session_reused(ssl) == 1;
  if (X509* peer = SSL_get1_peer_certificate(ssl)) {
    a.peer_version = X509_get_version(peer);
    X509_free(peer);
  }
  if (!c.request) {
    SSL_shutdown(ssl);
    return finish();
  }
  Bytes adu = c.raw ? *c.raw : mbap_frame(kProbeTid, s.unit, c.pdu ? *c.pdu : kProbePdu);
  if (SSL_write(ssl, adu.data(), int(adu.size())) <= 0) {
    a.after = Attempt::After::closed;
    return finish();
  }
  // Read until one whole ADU, the connection's end, or the timeout
  // (SO_RCVTIMEO set by connect_tcp).
  Bytes in;
  for (;;) {
    a.raw_reply = in;
    auto h = parse_mbap(in);
    if (c.raw) {
      // A bare PDU sent: a bare PDU reply to FC 03 is whole at its byte count (or 2 bytes, an exception).
      if (in.size() >= 2 && ((in[0] & 0x80) ? in.size() >= 2 : in.size() >= size_t(in[1]) + 2)) {
        a.after = Attempt::After::answered;
        break;
      }
    } else if (h && h->length_ok() && in.size() >= h->adu_size()) {
      a.after = Attempt::After::answered;
      a.reply.assign(in.begin() + kMbapHeader, in.begin() + ptrdiff_t(h->adu_size()));
      break;
    }
    uint8_t buf[512];
    errno = 0;
    int n = SSL_read(ssl, buf, sizeof buf);
    if (n > 0) {
      in.insert(in.end(), buf, buf + n);
      continue;
    }
    int e = SSL_get_error(ssl, n);
    bool timed_out = (e == SSL_ERROR_WANT_READ || e == SSL_ERROR_SYSCALL) && (errno == EAGAIN || errno == EWOULDBLOCK);
    a.after = timed_out ? Attempt::After::silent : Attempt::After::closed;
    break;
  }
  if (a.after == Attempt::After::answered) {
    // TLS 1.3 tickets come after the handshake: read by now.
    if (SSL_SESSION* got = SSL_get1_session(ssl)) a.session.reset(got, SSL_SESSION_free);
    if (c.close) {
      // MB-TCP-Security v2.1 §8.1 (TLS, RFC 8446 §6.1): each side sends
      // close_notify before closing its write side.
      int rc = SSL_shutdown(ssl);
      if (rc == 0) {
        uint8_t buf[64];
        errno = 0;
        int n = SSL_read(ssl, buf, sizeof buf);
        int e = SSL_get_error(ssl, n);
        if (n <= 0 && e == SSL_ERROR_ZERO_RETURN) a.close_notify_back = true;
        else if (n <= 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) a.close_text = "no close_notify and no close within the timeout";
        else a.close_text = "the connection ended without close_notify";
      } else if (rc == 1) {
        a.close_notify_back = true;
      }
    }
  }
  return finish();
}

std::string alert_text(const Attempt& a) {
  if (!a.alert) return "";
  // TLS 1.3's certificate_required (RFC 8446 §6.2) is newer than OpenSSL 3.0's names.
  std::string name = *a.alert == 116 ? "certificate required" : SSL_alert_desc_string_long(*a.alert);
  return fmt::format(" (alert {}: {})", *a.alert, name);
}

// "refused" when the handshake failed or the connection ended before a reply;
// "accepted" when the request was answered.
std::string admission(const Attempt& a) {
  if (!a.tcp) return "error: " + a.error;
  if (!a.handshake) return "refused: handshake failed: " + a.error + alert_text(a);
  switch (a.after) {
    case Attempt::After::answered: return fmt::format("accepted: {} handshake, the request was answered ({})", a.version, to_hex(a.reply));
    case Attempt::After::closed: return fmt::format("refused: {} handshake completed, then the connection ended before a reply{}", a.version, alert_text(a));
    case Attempt::After::silent: return fmt::format("silent: {} handshake completed; neither a reply nor a close within the timeout", a.version);
    case Attempt::After::none: break;
  }
  return "accepted: handshake completed";
}

// A check, its level, and for a MUST or SHOULD the first word of a message
// that meets it (every other word fails it; "error:" is a check that could
// not be made).
struct Check {
  std::string id, clause, title, requirement;
  std::function<std::string(const ServerUnderTest&, std::string& skip)> run;
  Level level = Level::observed;
  std::string meets{};  // "refused", "requested", "mbap"
};

std::string client_file(const ServerUnderTest& s, const std::string& name, std::string& skip) {
  if (s.clients_dir.empty()) {
    skip = "needs clients=DIR in the target URI (a directory with " + name + ".crt and .key)";
    return "";
  }
  fs::path p = fs::path(s.clients_dir) / (name + ".crt");
  if (!fs::exists(p)) {
    skip = fmt::format("no {} in clients={}", p.filename().string(), s.clients_dir);
    return "";
  }
  return (fs::path(s.clients_dir) / name).string();
}

// Appendix B of MB-TCP-Security v2.1 numbers each requirement; its text could
// not be read from here (README.md, "Levels"), so no check cites a v2.1
// number. What a third party numbers the same requirement in v3.6 is named as
// such, unverified, for whoever checks it against Appendix B.
std::string unverified(const char* v36) {
  return fmt::format("v2.1's requirement number not verified (v3.6's {} as tmodbus's documentation numbers it)", v36);
}

std::vector<Check> checks() {
  std::vector<Check> v;
  const std::string hs = "MB-TCP-Security v2.1 §8.1";
  const std::string ver = "MB-TCP-Security v2.1 §10.1";
  const std::string authz = "MB-TCP-Security v2.1 §8.3";
  // The MBAP ADU inside TLS, unchanged: an MBAP request gets an MBAP reply.
  // A server that answers a bare PDU with a bare PDU (pymodbus's
  // ModbusTlsFramer, pymodbus #2014) carries no MBAP header.
  v.push_back({"mbap-inside-tls", "MB-TCP-Security v2.1 §6 (Figure 3); Appendix A (Figure 11)",
               "the MBAP ADU is carried unchanged inside TLS: an MBAP request gets an MBAP reply",
               "the Modbus/TCP ADU, MBAP header included, is carried inside TLS unchanged (§6 Figure 3 \"mbap PDU "
               "Encapsulated in TLS\", Appendix A Figure 11 \"TLS Transportation of mbap PDU\")",
               [](const ServerUnderTest& s, std::string&) -> std::string {
                 Attempt a = attempt(s, with_cert(s.files.cert, s.files.key));
                 if (!a.handshake) return "error: the handshake with the URI's own certificate failed: " + a.error;
                 if (a.after == Attempt::After::answered)
                   return fmt::format("mbap: the MBAP request was answered with an MBAP reply ({})", to_hex(a.reply));
                 // No MBAP reply: does the server speak bare PDUs?
                 Client bare = with_cert(s.files.cert, s.files.key);
                 bare.raw = kProbePdu;
                 Attempt b = attempt(s, bare);
                 bool pdu_reply = b.raw_reply.size() >= 2 && (b.raw_reply[0] & 0x7F) == kProbePdu[0] &&
                                  (b.raw_reply[0] == 0x83 ? b.raw_reply.size() == 2 : b.raw_reply[1] + 2u == b.raw_reply.size());
                 if (pdu_reply)
                   return fmt::format("bare-pdu: {}: the MBAP request went {}; the bare PDU {} was answered with {}", kNoMbap,
                                      a.after == Attempt::After::silent ? "unanswered" : "without a reply (closed)",
                                      to_hex(kProbePdu), to_hex(b.raw_reply));
                 if (!a.raw_reply.empty())
                   return fmt::format("not-mbap: {}: the MBAP request got {}", kNoMbap, to_hex(a.raw_reply));
                 return fmt::format("unanswered: the MBAP request got no reply inside TLS ({})",
                                    a.after == Attempt::After::silent ? "silence" : "the connection closed");
               },
               Level::must, "mbap"});
  auto older = [](int version, const char* name) {
    return [version, name](const ServerUnderTest& s, std::string&) {
      Client c = with_cert(s.files.cert, s.files.key);
      c.min_version = version;
      c.max_version = version;
      Attempt a = attempt(s, c);
      std::string r = admission(a);
      return r.rfind("accepted", 0) == 0 ? fmt::format("accepted: {} was negotiated ({})", name, a.version) : r;
    };
  };
  // The server's certificate is an X.509 version 3 certificate (§8.1: mutual
  // authentication by x.509v3 certificates). X509_get_version gives the
  // encoded value: 0 for v1 (no version field), 2 for v3.
  v.push_back({"server-certificate-x509v3", hs, "the server's certificate is an X.509 version 3 certificate",
               "mutual client/server authentication by X.509v3 certificates (§8.1 TLS Handshake; modbus.org: the protocol "
               "\"leverages X.509v3 digital certificates for authentication of the Server and Client\"); " +
                   unverified("R-02, R-03"),
               [](const ServerUnderTest& s, std::string&) -> std::string {
                 Client c = with_cert(s.files.cert, s.files.key);
                 c.request = false;
                 Attempt a = attempt(s, c);
                 if (!a.handshake) return "error: the handshake with the URI's own certificate failed: " + a.error;
                 if (a.peer_version < 0) return "error: the server sent no certificate";
                 if (a.peer_version == 2) return fmt::format("x509v3: {} server certificate is X.509 version 3", a.version);
                 return fmt::format("not-x509v3: {} server certificate is X.509 version {}, not the x.509v3 certificate "
                                    "MB-TCP-Security authenticates with",
                                    a.version, a.peer_version + 1);
               },
               Level::must, "x509v3"});
  v.push_back({"tls-1.0-refused", ver, "a client offering only TLS 1.0 is refused",
               "TLS 1.2 or later (§10.1 TLS Version); " + unverified("R-32, R-34"), older(TLS1_VERSION, "TLS 1.0")});
  v.push_back({"tls-1.1-refused", ver, "a client offering only TLS 1.1 is refused",
               "TLS 1.2 or later (§10.1 TLS Version); " + unverified("R-32, R-34"), older(TLS1_1_VERSION, "TLS 1.1")});
  v.push_back({"tls-1.2-accepted", ver, "a client offering only TLS 1.2 is let in",
               "TLS 1.2 is the version §10.2 specifies", [](const ServerUnderTest& s, std::string&) {
                 Client c = with_cert(s.files.cert, s.files.key);
                 c.min_version = c.max_version = TLS1_2_VERSION;
                 return admission(attempt(s, c));
               }});
  v.push_back({"asks-client-certificate", hs, "the server asks for the client's certificate (CertificateRequest)",
               "mutual authentication: the server authenticates the client by its x.509v3 certificate (pymodbus #2118 never "
               "asked); " + unverified("R-06, R-44"),
               [](const ServerUnderTest& s, std::string&) {
                 Attempt a = attempt(s, with_cert(s.files.cert, s.files.key));
                 if (!a.handshake) return "error: the handshake with the URI's own certificate failed: " + a.error;
                 return a.cert_requested ? fmt::format("requested: {} CertificateRequest received", a.version)
                                         : fmt::format("not-requested: {} handshake without a CertificateRequest", a.version);
               }});
  v.push_back({"refuses-no-certificate", hs, "a client without a certificate is refused",
               "mutual authentication; " + unverified("R-06, R-44"),
               [](const ServerUnderTest& s, std::string&) { return admission(attempt(s, Client{})); }});
  auto with_client = [&](const char* name) {
    return [name](const ServerUnderTest& s, std::string& skip) {
      std::string base = client_file(s, name, skip);
      if (base.empty()) return std::string();
      return admission(attempt(s, with_cert(base + ".crt", base + ".key")));
    };
  };
  v.push_back({"refuses-untrusted-certificate", hs, "a client whose certificate no trusted CA signed is refused",
               "the client's certificate is validated against the server's trust anchors", with_client("untrusted")});
  v.push_back({"refuses-expired-certificate", hs, "a client whose certificate has expired is refused",
               "the client's certificate is validated (RFC 5280 §6.1.3: the current time within its validity)", with_client("expired")});
  // A client certificate of X.509 version 1 (no extensions at all, so no
  // role either): the authentication is by x.509v3 certificates on both sides
  // (§8.1), so a server that verifies only the chain still lets it in.
  v.push_back({"refuses-v1-certificate", hs, "a client whose certificate is X.509 version 1 is refused",
               "mutual authentication by X.509v3 certificates (§8.1): a client certificate of another version is not "
               "one; " + unverified("R-02, R-03"),
               with_client("client-v1")});
  v.push_back({"refuses-two-roles", authz, "a certificate whose role extension holds two roles is refused",
               "one role per certificate, OID 1.3.6.1.4.1.50316.802.1; " + unverified("R-65"),
               with_client("two-roles")});
  v.push_back({"refuses-role-not-utf8string", authz, "a role encoded as a PrintableString, not a UTF8String, is refused",
               "the role is an ASN.1 UTF8String; " + unverified("R-21, R-22"), with_client("printable-role")});
  v.push_back({"no-role", authz, "a certificate without the role extension",
               "what a server does without a role is its own policy: recorded", with_client("no-role")});
  v.push_back({"role-authorization", authz, "a request the role may not make is refused with exception 01",
               "role-based client authorization: a request the role is not authorized for is answered with exception "
               "code 01 (Illegal Function), as this project reads §8.3's Figure 10",
               [](const ServerUnderTest& s, std::string& skip) -> std::string {
                 if (s.roles_file.empty()) {
                   skip = "needs roles=FILE in the target URI (what the server lets each role do)";
                   return "";
                 }
                 tls::Roles roles = tls::Roles::load(s.roles_file);
                 FILE* f = std::fopen(s.files.cert.c_str(), "r");
                 X509* x = f ? PEM_read_X509(f, nullptr, nullptr, nullptr) : nullptr;
                 if (f) std::fclose(f);
                 auto role = tls::role_of(x).name;
                 X509_free(x);
                 if (!role || !roles.has(*role)) {
                   skip = "the URI's certificate has no role the roles file names";
                   return "";
                 }
                 // A write the role may not make: FC 06 at the first address
                 // outside what it may write, or anywhere when it may not write.
                 std::optional<Bytes> denied;
                 for (uint32_t addr : {0u, 100u, 1000u, 0xFFFFu}) {
                   Bytes pdu{0x06, uint8_t(addr >> 8), uint8_t(addr), 0x00, 0x00};
                   if (!roles.refusal(*role, pdu).empty()) {
                     denied = pdu;
                     break;
                   }
                 }
                 if (!denied) {
                   skip = fmt::format("role '{}' may write everywhere the check looks", *role);
                   return "";
                 }
                 Client c = with_cert(s.files.cert, s.files.key);
                 c.pdu = *denied;
                 Attempt a = attempt(s, c);
                 if (a.after != Attempt::After::answered) return admission(a);
                 bool ex01 = a.reply.size() == 2 && a.reply[0] == 0x86 && a.reply[1] == 0x01;
                 return fmt::format("{}: role '{}' sent {} and got {}", ex01 ? "refused" : "answered", *role, to_hex(*denied),
                                    to_hex(a.reply));
               }});
  v.push_back({"close-notify", hs, "close_notify is answered with close_notify",
               "TLS closure alerts (RFC 8446 §6.1, RFC 5246 §7.2.1): each party sends close_notify before closing",
               [](const ServerUnderTest& s, std::string&) {
                 Client c = with_cert(s.files.cert, s.files.key);
                 c.close = true;
                 Attempt a = attempt(s, c);
                 if (a.after != Attempt::After::answered) return "error: the request was not answered: " + admission(a);
                 return a.close_notify_back ? std::string("sent: the server answered close_notify with its own")
                                            : "not-sent: " + a.close_text;
               }});
  v.push_back({"session-resumption", hs, "a second connection resumes the first one's session",
               "TLS session resumption (§8.1 Figure 7) is the server's to offer: recorded",
               [](const ServerUnderTest& s, std::string&) {
                 Client c = with_cert(s.files.cert, s.files.key);
                 c.close = true;
                 Attempt first = attempt(s, c);
                 if (!first.session) return "error: the first connection was not answered: " + admission(first);
                 Client again = with_cert(s.files.cert, s.files.key);
                 again.session = first.session.get();
                 Attempt second = attempt(s, again);
                 if (!second.handshake) return "error: the second handshake failed: " + second.error;
                 return second.resumed ? fmt::format("resumed: {} session resumed", second.version)
                                       : fmt::format("not-resumed: {} full handshake again", second.version);
               }});
  // The levels (README.md, "Levels"): what MB-TCP-Security v2.1 requires of a
  // server is MUST; what it leaves to the server stays OBSERVED.
  for (auto& c : v) {
    if (c.id == "tls-1.0-refused" || c.id == "tls-1.1-refused" || c.id == "refuses-no-certificate" ||
        c.id == "refuses-untrusted-certificate" || c.id == "refuses-expired-certificate" || c.id == "refuses-v1-certificate" ||
        c.id == "refuses-two-roles" ||
        c.id == "refuses-role-not-utf8string")
      c.level = Level::must, c.meets = "refused";
    if (c.id == "asks-client-certificate") c.level = Level::must, c.meets = "requested";
  }
  return v;
}

}  // namespace

ServerUnderTest from_uri(const std::string& text) {
  Uri u = parse_uri(text);
  if (u.scheme != "mbtls") throw std::invalid_argument(fmt::format("target '{}': not an mbtls:// URI", text));
  ServerUnderTest s;
  s.uri = text;
  s.host = u.host;
  if (u.port) s.port = u.port;
  s.files = {u.param("cert").value_or(""), u.param("key").value_or(""), u.param("ca").value_or("")};
  s.clients_dir = u.param("clients").value_or("");
  s.roles_file = u.param("roles").value_or("");
  if (auto unit = u.param("unit")) s.unit = uint8_t(std::stoi(*unit));
  if (auto t = u.param("timeout")) s.timeout_ms = std::stoi(*t);
  return s;
}

std::vector<std::string> check_names() {
  std::vector<std::string> out;
  for (const auto& c : checks()) out.push_back(c.id);
  return out;
}

std::vector<CheckListing> check_listing() {
  std::vector<CheckListing> out;
  for (const auto& c : checks()) out.push_back({c.id, c.clause, c.title, c.requirement, c.level});
  return out;
}

std::vector<CaseResult> check_server(const ServerUnderTest& s, const std::string& device_id) {
  std::vector<CaseResult> out;
  for (const auto& c : checks()) {
    CaseResult r;
    r.id = fmt::format("{}/security/{}", device_id, c.id);
    r.family = "security";
    r.clause = c.clause;
    r.level = c.level;
    r.title = c.title;
    r.requirement = c.requirement;
    auto t0 = Clock::now();
    std::string skip;
    try {
      r.message = c.run(s, skip);
    } catch (const std::exception& e) {
      r.message = std::string("error: ") + e.what();
    }
    if (!skip.empty()) {
      r.outcome = Outcome::skip;
      r.message = skip;
    } else {
      bool error = r.message.rfind("error:", 0) == 0;
      bool met = !c.meets.empty() && r.message.rfind(c.meets, 0) == 0;
      r.outcome = error ? Outcome::error : c.level == Level::observed ? Outcome::observed : met ? Outcome::pass : Outcome::fail;
    }
    r.duration_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    out.push_back(std::move(r));
  }
  return out;
}

}  // namespace mbc::conf::security
