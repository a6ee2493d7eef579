#include "serve/tls.h"

#include "serve/endpoint.h"

#include <arpa/inet.h>
#include <dirent.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/epoll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <list>
#include <mutex>
#include <stdexcept>
#include <thread>

#include <fmt/core.h>

namespace mbc::tls {

using Clock = std::chrono::steady_clock;

void CtxDeleter::operator()(SSL_CTX* c) const { SSL_CTX_free(c); }

std::string ssl_errors() {
  std::string out;
  while (unsigned long e = ERR_get_error()) {
    char buf[256];
    ERR_error_string_n(e, buf, sizeof buf);
    // "error:0A000086:SSL routines::certificate verify failed" -> the reason
    std::string s = buf;
    auto colon = s.rfind(':');
    if (colon != std::string::npos) s = s.substr(colon + 1);
    if (out.find(s) == std::string::npos) out += (out.empty() ? "" : "; ") + s;
  }
  return out;
}

static_assert(sizeof(sigset_t) <= 128);

NoSigpipe::NoSigpipe() {
  sigset_t pipe;
  sigemptyset(&pipe);
  sigaddset(&pipe, SIGPIPE);
  pthread_sigmask(SIG_BLOCK, &pipe, reinterpret_cast<sigset_t*>(old_));
}

NoSigpipe::~NoSigpipe() {
  sigset_t pipe;
  sigemptyset(&pipe);
  sigaddset(&pipe, SIGPIPE);
  timespec zero{0, 0};
  while (sigtimedwait(&pipe, nullptr, &zero) > 0) {
  }
  pthread_sigmask(SIG_SETMASK, reinterpret_cast<sigset_t*>(old_), nullptr);
}

namespace {

std::string strerr() { return std::strerror(errno); }

// A file a user names must be a regular file: a FIFO or a device would hang
// the reader. Throws naming the option.
void check_regular(const std::string& path, const std::string& name) {
  struct stat st{};
  if (::stat(path.c_str(), &st) != 0) throw std::runtime_error(fmt::format("{} {}: {}", name, path, strerr()));
  if (!S_ISREG(st.st_mode))
    throw std::runtime_error(fmt::format("{} {}: not a regular file (a device or a pipe has no end to read to)", name, path));
}

// A PEM file's first certificate; throws naming the option.
void check_pem_cert(const std::string& path, const std::string& name) {
  check_regular(path, name);
  FILE* f = std::fopen(path.c_str(), "r");
  if (!f) throw std::runtime_error(fmt::format("{} {}: {}", name, path, strerr()));
  X509* x = PEM_read_X509(f, nullptr, nullptr, nullptr);
  std::fclose(f);
  if (!x) {
    ERR_clear_error();
    throw std::runtime_error(fmt::format("{} {}: not a PEM certificate", name, path));
  }
  X509_free(x);
}

}  // namespace

void check_files(const Files& f, const std::string& cert_name, const std::string& key_name, const std::string& ca_name) {
  if (f.cert.empty() != f.key.empty())
    throw std::runtime_error(fmt::format("{} and {} go together: give both or neither", cert_name, key_name));
  if (!f.ca.empty()) check_pem_cert(f.ca, ca_name);
  if (f.cert.empty()) return;
  check_pem_cert(f.cert, cert_name);
  struct stat st{};
  if (::stat(f.key.c_str(), &st) != 0) throw std::runtime_error(fmt::format("{} {}: {}", key_name, f.key, strerr()));
  // A private key others can read is no longer private (as ssh refuses one).
  if (!S_ISREG(st.st_mode))
    throw std::runtime_error(fmt::format("{} {}: not a regular file (a device or a pipe has no end to read to)", key_name, f.key));
  if (st.st_mode & (S_IRWXG | S_IRWXO))
    throw std::runtime_error(fmt::format("{} {}: readable by group or others (mode {:04o}); chmod 600 it", key_name,
                                         f.key, unsigned(st.st_mode & 07777)));
  FILE* kf = std::fopen(f.key.c_str(), "r");
  if (!kf) throw std::runtime_error(fmt::format("{} {}: {}", key_name, f.key, strerr()));
  EVP_PKEY* key = PEM_read_PrivateKey(kf, nullptr, nullptr, nullptr);
  std::fclose(kf);
  if (!key) {
    ERR_clear_error();
    throw std::runtime_error(fmt::format("{} {}: not a PEM private key (or one with a passphrase)", key_name, f.key));
  }
  FILE* cf = std::fopen(f.cert.c_str(), "r");
  X509* x = cf ? PEM_read_X509(cf, nullptr, nullptr, nullptr) : nullptr;
  if (cf) std::fclose(cf);
  bool match = x && X509_check_private_key(x, key) == 1;
  X509_free(x);
  EVP_PKEY_free(key);
  ERR_clear_error();
  if (!match) throw std::runtime_error(fmt::format("{} {}: does not match the certificate {}", key_name, f.key, f.cert));
}

// ---- roles ----

Role role_of(X509* cert) {
  Role r;
  if (!cert) return r;
  ASN1_OBJECT* oid = OBJ_txt2obj(kRoleOid, 1);
  int count = 0, at = -1;
  int found = -1;
  while ((at = X509_get_ext_by_OBJ(cert, oid, at)) >= 0) {
    ++count;
    found = at;
  }
  ASN1_OBJECT_free(oid);
  if (count == 0) return r;
  if (count > 1) {
    r.problem = fmt::format("{} role extensions; one role per certificate", count);
    return r;
  }
  ASN1_OCTET_STRING* data = X509_EXTENSION_get_data(X509_get_ext(cert, found));
  const unsigned char* p = ASN1_STRING_get0_data(data);
  long len = ASN1_STRING_length(data);
  const unsigned char* end = p + len;
  // The extension's value is one DER UTF8String, nothing after it.
  ASN1_TYPE* v = d2i_ASN1_TYPE(nullptr, &p, len);
  if (!v) {
    ERR_clear_error();
    r.problem = "the role extension is not DER";
    return r;
  }
  if (v->type == V_ASN1_SEQUENCE) {
    r.problem = "the role extension holds a SEQUENCE (more than one role); one role per certificate";
  } else if (v->type != V_ASN1_UTF8STRING) {
    r.problem = fmt::format("the role is an ASN.1 {}, not a UTF8String", ASN1_tag2str(v->type));
  } else if (p != end) {
    r.problem = "bytes follow the role's UTF8String (more than one role)";
  } else {
    r.name = std::string(reinterpret_cast<const char*>(ASN1_STRING_get0_data(v->value.utf8string)),
                         size_t(ASN1_STRING_length(v->value.utf8string)));
    if (r.name->empty()) {
      r.name.reset();
      r.problem = "the role is empty";
    }
  }
  ASN1_TYPE_free(v);
  return r;
}

std::vector<std::pair<uint32_t, uint32_t>> addressed_ranges(std::span<const uint8_t> pdu) {
  auto u16 = [&](size_t i) { return uint32_t(pdu[i] << 8 | pdu[i + 1]); };
  auto span = [&](size_t at_addr, size_t at_qty) {
    uint32_t a = u16(at_addr), q = u16(at_qty);
    return std::pair<uint32_t, uint32_t>{a, q ? a + q - 1 : a};
  };
  if (pdu.empty()) return {};
  switch (pdu[0]) {
    case 1: case 2: case 3: case 4: case 15: case 16:
      if (pdu.size() >= 5) return {span(1, 3)};
      break;
    case 5: case 6: case 22:
      if (pdu.size() >= 3) return {{u16(1), u16(1)}};
      break;
    case 23:
      if (pdu.size() >= 9) return {span(1, 3), span(5, 7)};
      break;
    default: break;
  }
  return {};
}

Roles Roles::load(const std::string& path) {
  auto where = [&](const YAML::Node& n) {
    auto m = n.Mark();
    return fmt::format("{}:{}:{}: error: roles: ", path, m.line + 1, m.column + 1);
  };
  YAML::Node root;
  check_regular(path, "--roles");
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::runtime_error(fmt::format("{}: error: roles: cannot read the file", path));
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(fmt::format("{}:{}:{}: error: roles: {}", path, e.mark.line + 1, e.mark.column + 1, e.msg));
  }
  if (!root.IsMap() || !root["mbconform_roles"] || root["mbconform_roles"].as<std::string>("") != "1")
    throw std::runtime_error(fmt::format("{}:1:1: error: roles: expected 'mbconform_roles: 1' and 'roles:'", path));
  for (const auto& kv : root)
    if (auto k = kv.first.as<std::string>(); k != "mbconform_roles" && k != "roles")
      throw std::runtime_error(where(kv.first) + fmt::format("unknown key '{}'", k));
  YAML::Node roles = root["roles"];
  if (!roles || !roles.IsMap()) throw std::runtime_error(fmt::format("{}:1:1: error: roles: 'roles:' must map each role to its rules", path));
  Roles out;
  auto number = [&](const YAML::Node& n, uint32_t hi) {
    std::string s = n.as<std::string>("");
    size_t used = 0;
    unsigned long v = 0;
    try {
      v = std::stoul(s, &used, 0);
    } catch (const std::exception&) {
      used = 0;
    }
    if (s.empty() || used != s.size() || v > hi) throw std::runtime_error(where(n) + fmt::format("'{}' is not a number 0..{}", s, hi));
    return uint32_t(v);
  };
  for (const auto& role : roles) {
    std::string name = role.first.as<std::string>();
    if (!role.second.IsSequence()) throw std::runtime_error(where(role.second) + fmt::format("role '{}': a list of rules", name));
    auto& rules = out.rules_[name];
    for (const auto& r : role.second) {
      if (!r.IsMap() || !r["functions"]) throw std::runtime_error(where(r) + "a rule needs 'functions: [...]'");
      Rule rule;
      for (const auto& kv : r)
        if (auto k = kv.first.as<std::string>(); k != "functions" && k != "addresses")
          throw std::runtime_error(where(kv.first) + fmt::format("unknown key '{}' (functions, addresses)", k));
      for (const auto& f : r["functions"]) {
        uint32_t fc = number(f, 127);
        if (fc == 0) throw std::runtime_error(where(f) + "function code 0 does not exist");
        rule.functions.push_back(uint8_t(fc));
      }
      if (r["addresses"]) {
        for (const auto& a : r["addresses"]) {
          std::string s = a.as<std::string>("");
          auto dash = s.find('-');
          YAML::Node lo = YAML::Node(s.substr(0, dash)), hi = YAML::Node(dash == std::string::npos ? s : s.substr(dash + 1));
          uint32_t from, to;
          try {
            from = number(lo, 65535);
            to = number(hi, 65535);
          } catch (const std::runtime_error&) {
            throw std::runtime_error(where(a) + fmt::format("'{}': expected FIRST-LAST, addresses 0..65535", s));
          }
          if (to < from) throw std::runtime_error(where(a) + fmt::format("'{}': LAST below FIRST", s));
          rule.addresses.emplace_back(uint16_t(from), uint16_t(to));
        }
      }
      rules.push_back(std::move(rule));
    }
  }
  return out;
}

std::string Roles::refusal(const std::string& role, std::span<const uint8_t> pdu) const {
  auto it = rules_.find(role);
  if (it == rules_.end()) return fmt::format("role '{}' is not in the roles file", role);
  if (pdu.empty()) return "empty PDU";
  uint8_t fc = pdu[0];
  auto spans = addressed_ranges(pdu);
  for (const auto& rule : it->second) {
    if (std::find(rule.functions.begin(), rule.functions.end(), fc) == rule.functions.end()) continue;
    if (rule.addresses.empty()) return "";
    bool all = true;
    for (const auto& [lo, hi] : spans) {
      bool in = false;
      for (const auto& [a, b] : rule.addresses) in = in || (lo >= a && hi <= b);
      all = all && in;
    }
    if (all && !spans.empty()) return "";
  }
  return fmt::format("role '{}' may not use function code {:02X}{}", role, fc,
                     spans.empty() ? "" : fmt::format(" at {}-{}", spans.front().first, spans.front().second));
}

// ---- contexts ----

namespace {

int g_require_role_index = -1;

// The role check runs where the chain is verified: a client certificate that
// is not X.509v3, or has an unusable role extension, fails the handshake
// (bad_certificate).
int verify_role(int ok, X509_STORE_CTX* store) {
  if (!ok) return 0;
  if (X509_STORE_CTX_get_error_depth(store) != 0) return ok;
  auto* ssl = static_cast<SSL*>(X509_STORE_CTX_get_ex_data(store, SSL_get_ex_data_X509_STORE_CTX_idx()));
  SSL_CTX* ctx = ssl ? SSL_get_SSL_CTX(ssl) : nullptr;
  bool require = ctx && SSL_CTX_get_ex_data(ctx, g_require_role_index) != nullptr;
  X509* cert = X509_STORE_CTX_get_current_cert(store);
  // §8.1: authentication by X.509v3 certificates; OpenSSL verifies a
  // version 1 leaf's chain like any other, so its version is checked here.
  if (X509_get_version(cert) != X509_VERSION_3) {
    X509_STORE_CTX_set_error(store, X509_V_ERR_APPLICATION_VERIFICATION);
    return 0;
  }
  Role r = role_of(cert);
  if (!r.problem.empty() || (require && !r.name)) {
    X509_STORE_CTX_set_error(store, X509_V_ERR_APPLICATION_VERIFICATION);
    return 0;
  }
  return 1;
}

Ctx base_context(const SSL_METHOD* method, const Files& f) {
  Ctx ctx(SSL_CTX_new(method));
  if (!ctx) throw std::runtime_error("TLS: " + ssl_errors());
  // MB-TCP-Security v2.1 §10.1: TLS 1.2 at least.
  SSL_CTX_set_min_proto_version(ctx.get(), TLS1_2_VERSION);
  SSL_CTX_set_mode(ctx.get(), SSL_MODE_ENABLE_PARTIAL_WRITE | SSL_MODE_ACCEPT_MOVING_WRITE_BUFFER);
  // §10.5: no renegotiation.
  SSL_CTX_set_options(ctx.get(), SSL_OP_NO_RENEGOTIATION);
  if (!f.cert.empty()) {
    if (SSL_CTX_use_certificate_chain_file(ctx.get(), f.cert.c_str()) != 1)
      throw std::runtime_error(fmt::format("certificate {}: {}", f.cert, ssl_errors()));
    if (SSL_CTX_use_PrivateKey_file(ctx.get(), f.key.c_str(), SSL_FILETYPE_PEM) != 1 || SSL_CTX_check_private_key(ctx.get()) != 1)
      throw std::runtime_error(fmt::format("key {}: {}", f.key, ssl_errors()));
  }
  if (!f.ca.empty() && SSL_CTX_load_verify_locations(ctx.get(), f.ca.c_str(), nullptr) != 1)
    throw std::runtime_error(fmt::format("CA {}: {}", f.ca, ssl_errors()));
  return ctx;
}

}  // namespace

Ctx server_context(const Files& f, bool require_role) {
  if (g_require_role_index < 0) g_require_role_index = SSL_CTX_get_ex_new_index(0, nullptr, nullptr, nullptr, nullptr);
  Ctx ctx = base_context(TLS_server_method(), f);
  // §8.1: mutual authentication; a client without a certificate is refused.
  SSL_CTX_set_verify(ctx.get(), SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT, verify_role);
  SSL_CTX_set_ex_data(ctx.get(), g_require_role_index, require_role ? ctx.get() : nullptr);
  if (!f.ca.empty()) {
    if (STACK_OF(X509_NAME)* names = SSL_load_client_CA_file(f.ca.c_str())) SSL_CTX_set_client_CA_list(ctx.get(), names);
  }
  static const unsigned char sid[] = "mbconform-mbaps";
  SSL_CTX_set_session_id_context(ctx.get(), sid, sizeof sid - 1);
  return ctx;
}

Ctx client_context(const Files& f) {
  Ctx ctx = base_context(TLS_client_method(), f);
  SSL_CTX_set_verify(ctx.get(), SSL_VERIFY_PEER, nullptr);
  return ctx;
}

// ---- sockets ----

namespace {

using serve::set_nonblocking;
using serve::sockaddr_text;

int listen_on(const std::string& host, uint16_t port, std::string& bound) {
  serve::TcpListener l = serve::listen_tcp("tls", host, port);
  bound = l.bound;
  return l.fd;
}

bool same_addr(const sockaddr_storage& a, const sockaddr_storage& b) {
  if (a.ss_family != b.ss_family) return false;
  if (a.ss_family == AF_INET) {
    auto* x = reinterpret_cast<const sockaddr_in*>(&a);
    auto* y = reinterpret_cast<const sockaddr_in*>(&b);
    return x->sin_port == y->sin_port && x->sin_addr.s_addr == y->sin_addr.s_addr;
  }
  return false;
}

// The plain listener of the client side is on loopback, where any local
// process could connect: a connection is relayed only when one of this
// process's own sockets is its other end.
bool from_this_process(int accepted) {
  sockaddr_storage peer{}, self{};
  socklen_t len = sizeof peer;
  if (getpeername(accepted, reinterpret_cast<sockaddr*>(&peer), &len) != 0) return false;
  len = sizeof self;
  getsockname(accepted, reinterpret_cast<sockaddr*>(&self), &len);
  DIR* d = opendir("/proc/self/fd");
  if (!d) return false;
  bool ours = false;
  while (dirent* e = readdir(d)) {
    int fd = std::atoi(e->d_name);
    if (fd <= 2 || fd == accepted || fd == dirfd(d)) continue;
    sockaddr_storage a{}, b{};
    socklen_t la = sizeof a, lb = sizeof b;
    if (getsockname(fd, reinterpret_cast<sockaddr*>(&a), &la) != 0) continue;
    if (getpeername(fd, reinterpret_cast<sockaddr*>(&b), &lb) != 0) continue;
    if (same_addr(a, peer) && same_addr(b, self)) {
      ours = true;
      break;
    }
  }
  closedir(d);
  return ours;
}

}  // namespace

int connect_tcp(const std::string& host, uint16_t port, int timeout_ms, std::string& why) {
  addrinfo hints{}, *res = nullptr;
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICSERV;
  std::string p = std::to_string(port);
  if (int rc = getaddrinfo(host.c_str(), p.c_str(), &hints, &res); rc != 0) {
    why = gai_strerror(rc);
    return -1;
  }
  int fd = -1;
  for (addrinfo* ai = res; ai && fd < 0; ai = ai->ai_next) {
    fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (fd < 0) continue;
    int rc = ::connect(fd, ai->ai_addr, ai->ai_addrlen);
    if (rc != 0 && errno == EINPROGRESS) {
      pollfd pf{fd, POLLOUT, 0};
      rc = poll(&pf, 1, timeout_ms) == 1 ? 0 : -1;
      int err = 0;
      socklen_t len = sizeof err;
      if (rc == 0) getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len);
      else err = ETIMEDOUT;
      if (err) {
        errno = err;
        rc = -1;
      }
    }
    if (rc != 0) {
      why = strerr();
      ::close(fd);
      fd = -1;
    }
  }
  freeaddrinfo(res);
  if (fd < 0) return -1;
  int flags = fcntl(fd, F_GETFL);
  fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  timeval tv{timeout_ms / 1000, (timeout_ms % 1000) * 1000};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  return fd;
}

void expect_host(SSL* ssl, const std::string& host) {
  in_addr a4{};
  in6_addr a6{};
  if (inet_pton(AF_INET, host.c_str(), &a4) == 1 || inet_pton(AF_INET6, host.c_str(), &a6) == 1) {
    X509_VERIFY_PARAM_set1_ip_asc(SSL_get0_param(ssl), host.c_str());
  } else {
    SSL_set1_host(ssl, host.c_str());
    SSL_set_tlsext_host_name(ssl, host.c_str());
  }
}

// ---- the relay ----

namespace {

// A TLS handshake that has not finished after this long is dropped (a peer
// that connects and says nothing must not hold a slot for long).
constexpr std::chrono::seconds kHandshakeLimit{5};
// Handshakes under way at once, in all and from one peer address: past
// either cap the oldest such handshake makes room for the newcomer.
constexpr size_t kMaxHandshakes = 256;
constexpr size_t kMaxPeerHandshakes = 32;
// Descriptors kept free of TLS connections: listeners, the epoll sets, wake
// pipes, stdio, and what the serve loop opens beside them.
constexpr size_t kReservedFds = 64;
// An established server-side connection holds three descriptors: its TCP
// socket and both ends of the socketpair to the serve loop.
constexpr size_t kFdsPerConnection = 3;
// Decrypted bytes held for the plain side at once; past it, nothing more is
// read from the TLS side until they are written.
constexpr size_t kBufferBound = 64 * 1024;
// The door thread's nice value above the process's: under load the
// handshakes (the CPU an attacker can make serve spend) yield to the relay
// of the established connections and to the serve loop.
constexpr int kDoorNice = 5;
// Keys of the epoll sets that are no connection (a connection's key is the
// address of its Watch, far below these).
constexpr uint64_t kWakeKey = uint64_t(1) << 62;
constexpr uint64_t kListenerKey = uint64_t(1) << 61;

struct Pipe;
// One descriptor of a connection in an epoll set.
struct Watch {
  Pipe* pipe = nullptr;
  bool plain = false;
  uint32_t armed = 0;
  bool registered = false;
};

struct Pipe {
  int net = -1;    // the TCP connection carrying TLS
  int plain = -1;  // the plain side
  SSL* ssl = nullptr;
  bool handshaking = true;
  Clock::time_point started;
  std::function<int(const Peer&)> inner;  // server side: where the plain side comes from
  Peer info;                              // server side: set when the handshake is done
  std::string to_plain, to_tls;
  bool tls_eof = false;     // close_notify from the TLS peer
  bool plain_eof = false;   // EOF from the plain side
  bool want_write = false;  // the last SSL call wanted to write
  bool done = false;
  bool doomed = false;      // queued for removal this round
  bool queued = false;      // queued for a step this round
  std::string peer;         // the peer's address without the port (the per-peer cap)
  Watch net_watch, plain_watch;
  std::list<Pipe>::iterator self;                // in its loop's pipes (the relay's: least recently active first)
  std::list<Pipe*>::iterator shaking;            // in Impl::handshakes while handshaking
  bool counted = false;                          // in the handshake counts

  Pipe() {
    net_watch.pipe = plain_watch.pipe = this;
    plain_watch.plain = true;
  }
  Pipe(const Pipe&) = delete;
  ~Pipe() {
    if (ssl) SSL_free(ssl);
    if (net >= 0) ::close(net);
    if (plain >= 0) ::close(plain);
  }
};

struct TlsListener {
  int fd = -1;
  bool tls = true;  // false: the plain loopback side of a client relay
  SSL_CTX* ctx = nullptr;
  std::function<int(const Peer&)> inner;
  std::string remote_host;
  uint16_t remote_port = 0;
  int timeout_ms = 1000;
};

std::string host_of(const sockaddr_storage& ss) {
  char buf[INET6_ADDRSTRLEN] = "";
  if (ss.ss_family == AF_INET) inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in*>(&ss)->sin_addr, buf, sizeof buf);
  else if (ss.ss_family == AF_INET6) inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6*>(&ss)->sin6_addr, buf, sizeof buf);
  return buf;
}

// One thread's epoll set (level triggered: a round costs the connections
// that are ready, no limit on descriptors) and the connections it owns.
struct Loop {
  int epfd = -1;
  int wake[2] = {-1, -1};
  std::list<Pipe> pipes;
  std::vector<Pipe*> doomed;
  size_t fds_used = 0;  // by its connections
  size_t fd_budget = 0;
};

}  // namespace

// Two threads. The door thread accepts and runs the handshakes (their
// caps, their time limit); a connection whose handshake is done goes to the
// relay thread, which pumps the bytes of the established connections. So
// an attacker's handshakes (milliseconds of CPU each, an OpenSSL 3 server
// handshake with a client certificate) never stand before a good client's
// bytes in one thread's queue, and the relay thread, asleep most of the
// time, is woken at once when they come; the door thread runs kDoorNice
// lower. The descriptor budget is split: the handshakes' share (one each)
// and the established connections' (three each). Every SSL call starts with
// an empty error queue (OpenSSL's error queue is per thread: an error one
// connection left behind made SSL_get_error report it for the next
// connection, which was then dropped).
struct Relay::Impl {
  std::vector<Ctx> ctxs;
  std::vector<TlsListener> listeners;
  Loop door, relay;
  std::list<Pipe*> handshakes;   // the door's, oldest first
  std::map<std::string, size_t> peer_handshakes;
  size_t max_handshakes = kMaxHandshakes;
  std::mutex handoff_mutex;
  std::list<Pipe> handoff;       // handshakes done, for the relay thread
  int spare = -1;                // a descriptor given up to refuse a connection cleanly at the file limit
  std::thread door_thread, relay_thread;
  std::atomic<bool> stop{false};
  mutable std::mutex error_mutex;
  std::string last_error;

  ~Impl() {
    stop = true;
    for (Loop* l : {&door, &relay})
      if (l->wake[1] >= 0) {
        char c = 1;
        (void)!::write(l->wake[1], &c, 1);
      }
    if (door_thread.joinable()) door_thread.join();
    if (relay_thread.joinable()) relay_thread.join();
    door.pipes.clear();
    handoff.clear();
    relay.pipes.clear();
    for (auto& l : listeners) ::close(l.fd);
    for (Loop* l : {&door, &relay}) {
      if (l->wake[0] >= 0) ::close(l->wake[0]);
      if (l->wake[1] >= 0) ::close(l->wake[1]);
      if (l->epfd >= 0) ::close(l->epfd);
    }
    if (spare >= 0) ::close(spare);
  }

  void set_error(std::string e) {
    std::lock_guard<std::mutex> g(error_mutex);
    last_error = std::move(e);
  }

  // ---- bookkeeping ----

  static void arm(Loop& l, Watch& w, int fd, uint32_t want) {
    if (fd < 0) return;
    if (w.registered && w.armed == want) return;
    epoll_event e{};
    e.events = want;
    e.data.u64 = reinterpret_cast<uintptr_t>(&w);
    if (epoll_ctl(l.epfd, w.registered ? EPOLL_CTL_MOD : EPOLL_CTL_ADD, fd, &e) == 0) {
      w.registered = true;
      w.armed = want;
    }
  }

  // Registers the connection for what it can use now.
  static void update(Loop& l, Pipe& p) {
    if (p.done) return;
    uint32_t net = (p.to_plain.size() < kBufferBound && !p.tls_eof ? uint32_t(EPOLLIN) : 0u) | (p.want_write ? uint32_t(EPOLLOUT) : 0u);
    if (p.handshaking) net = uint32_t(EPOLLIN) | (p.want_write ? uint32_t(EPOLLOUT) : 0u);
    arm(l, p.net_watch, p.net, net);
    if (!p.handshaking && p.plain >= 0) {
      uint32_t plain = (p.to_tls.size() < kBufferBound && !p.plain_eof ? uint32_t(EPOLLIN) : 0u) | (!p.to_plain.empty() ? uint32_t(EPOLLOUT) : 0u);
      arm(l, p.plain_watch, p.plain, plain);
    }
  }

  void uncount(Pipe& p) {
    if (!p.counted) return;
    p.counted = false;
    handshakes.erase(p.shaking);
    if (auto it = peer_handshakes.find(p.peer); it != peer_handshakes.end() && --it->second == 0) peer_handshakes.erase(it);
  }

  // Closes the connection now (its descriptors come free at once) and queues
  // it for removal at the end of the round.
  void doom(Loop& l, Pipe& p) {
    if (p.doomed) return;
    p.done = p.doomed = true;
    uncount(p);
    size_t held = size_t(p.net >= 0) + (p.plain >= 0 ? kFdsPerConnection - 1 : 0);
    l.fds_used -= std::min(l.fds_used, held);
    if (p.ssl) SSL_free(p.ssl);
    p.ssl = nullptr;
    if (p.net >= 0) ::close(p.net);
    if (p.plain >= 0) ::close(p.plain);
    p.net = p.plain = -1;
    l.doomed.push_back(&p);
  }

  static void bury(Loop& l) {
    for (Pipe* p : l.doomed) l.pipes.erase(p->self);
    l.doomed.clear();
  }

  // The established connection unused the longest (Modbus Messaging on
  // TCP/IP Implementation Guide V1.0b §4.2.1.2) makes room, `except` kept.
  bool make_room(const Pipe* except) {
    for (auto& p : relay.pipes)
      if (!p.doomed && &p != except) {
        doom(relay, p);
        return true;
      }
    return false;
  }

  // ---- the door: accepting and handshakes ----

  void accept_tls(TlsListener& l, Clock::time_point now) {
    for (int n = 0; n < 256; ++n) {  // bounded: the others are served between bursts
      sockaddr_storage ss{};
      socklen_t len = sizeof ss;
      int fd = accept4(l.fd, reinterpret_cast<sockaddr*>(&ss), &len, SOCK_NONBLOCK | SOCK_CLOEXEC);
      if (fd < 0) {
        if ((errno == EMFILE || errno == ENFILE) && spare >= 0) {
          // At the file limit: refuse the newcomer cleanly (accept and close
          // it with the descriptor kept for this) and make room for the next.
          ::close(spare);
          spare = -1;
          int refused = accept4(l.fd, nullptr, nullptr, SOCK_CLOEXEC);
          if (refused >= 0) ::close(refused);
          spare = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
          if (!handshakes.empty()) doom(door, *handshakes.front());
          continue;
        }
        return;  // EAGAIN, or an aborted connection
      }
      int one = 1;
      setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      if (!l.tls) {
        accept_plain(l, fd);
        continue;
      }
      Pipe& p = door.pipes.emplace_back();
      p.self = std::prev(door.pipes.end());
      p.net = fd;
      ++door.fds_used;
      p.peer = host_of(ss);
      p.started = now;
      p.inner = l.inner;
      // The caps: the oldest handshake of this peer, else the oldest of all,
      // makes room.
      size_t& mine = peer_handshakes[p.peer];
      if (mine >= kMaxPeerHandshakes)
        for (Pipe* q : handshakes)
          if (q->peer == p.peer) {
            doom(door, *q);
            break;
          }
      if (handshakes.size() >= max_handshakes) doom(door, *handshakes.front());
      ++peer_handshakes[p.peer];
      handshakes.push_back(&p);
      p.shaking = std::prev(handshakes.end());
      p.counted = true;
      p.ssl = SSL_new(l.ctx);
      if (!p.ssl) {
        doom(door, p);
        continue;
      }
      SSL_set_fd(p.ssl, fd);
      SSL_set_accept_state(p.ssl);
      shake(p);
    }
  }

  // Client side: a connection from this process goes out over TLS. The
  // outgoing connect and handshake block the door thread (bounded by the
  // timeout): a target has one connection at a time.
  void accept_plain(TlsListener& l, int fd) {
    if (!from_this_process(fd)) {
      ::close(fd);
      return;
    }
    std::string why;
    int net = connect_tcp(l.remote_host, l.remote_port, l.timeout_ms, why);
    if (net < 0) {
      set_error(fmt::format("cannot connect to {}:{}: {}", l.remote_host, l.remote_port, why));
      ::close(fd);
      return;
    }
    ERR_clear_error();
    SSL* ssl = SSL_new(l.ctx);
    SSL_set_fd(ssl, net);
    expect_host(ssl, l.remote_host);
    if (SSL_connect(ssl) != 1) {
      long v = SSL_get_verify_result(ssl);
      std::string e = ssl_errors();
      if (v != X509_V_OK) e += fmt::format(" ({})", X509_verify_cert_error_string(v));
      set_error(fmt::format("TLS handshake with {}:{} failed: {}", l.remote_host, l.remote_port, e.empty() ? "connection closed" : e));
      SSL_free(ssl);
      ::close(net);
      ::close(fd);
      return;
    }
    set_error("");
    set_nonblocking(net);
    Pipe& p = door.pipes.emplace_back();
    p.self = std::prev(door.pipes.end());
    p.net = net;
    p.plain = fd;
    p.ssl = ssl;
    p.handshaking = false;
    hand_over(p);
  }

  // Runs the handshake as far as it goes without blocking; when it is done,
  // hands the connection to the relay thread.
  void shake(Pipe& p) {
    if (p.done || !p.ssl) return;
    ERR_clear_error();
    int rc = SSL_do_handshake(p.ssl);
    if (rc != 1) {
      int e = SSL_get_error(p.ssl, rc);
      ERR_clear_error();
      if (e == SSL_ERROR_WANT_READ || e == SSL_ERROR_WANT_WRITE) {
        p.want_write = e == SSL_ERROR_WANT_WRITE;
        update(door, p);
        return;
      }
      // Refused: the alert went out with the failure. Close the write side
      // and read what the client already sent, so that closing does not
      // reset the connection and drop the alert before the client reads it.
      ::shutdown(p.net, SHUT_WR);
      char sink[4096];
      for (int i = 0; i < 16 && ::recv(p.net, sink, sizeof sink, 0) > 0; ++i) {
      }
      doom(door, p);
      return;
    }
    p.handshaking = false;
    p.want_write = false;
    sockaddr_storage ss{};
    socklen_t len = sizeof ss;
    getpeername(p.net, reinterpret_cast<sockaddr*>(&ss), &len);
    p.info.address = sockaddr_text(ss);
    p.info.version = SSL_get_version(p.ssl);
    X509* cert = SSL_get1_peer_certificate(p.ssl);
    p.info.role = role_of(cert).name;
    X509_free(cert);
    hand_over(p);
  }

  // Out of the door's epoll set and bookkeeping, into the relay's hands.
  void hand_over(Pipe& p) {
    uncount(p);
    if (p.net_watch.registered) epoll_ctl(door.epfd, EPOLL_CTL_DEL, p.net, nullptr);
    p.net_watch.registered = p.plain_watch.registered = false;
    p.net_watch.armed = p.plain_watch.armed = 0;
    if (p.handshaking == false && p.plain < 0) door.fds_used -= std::min<size_t>(door.fds_used, 1);
    {
      std::lock_guard<std::mutex> g(handoff_mutex);
      handoff.splice(handoff.end(), door.pipes, p.self);
    }
    char c = 1;
    (void)!::write(relay.wake[1], &c, 1);
  }

  void run_door() {
    NoSigpipe no_sigpipe;  // a peer that closed must not kill the process
    errno = 0;
    const int base = getpriority(PRIO_PROCESS, 0);
    if (errno == 0) (void)setpriority(PRIO_PROCESS, pid_t(gettid()), std::min(19, base + kDoorNice));
    std::vector<epoll_event> ready(256);
    std::vector<Pipe*> stepped;
    while (!stop) {
      // Wake for the oldest handshake's time limit, at the latest.
      int timeout_ms = 1000;
      if (!handshakes.empty()) {
        auto due = handshakes.front()->started + kHandshakeLimit - Clock::now();
        timeout_ms = int(std::clamp<int64_t>(std::chrono::duration_cast<std::chrono::milliseconds>(due).count() + 1, 0, 1000));
      }
      int n = epoll_wait(door.epfd, ready.data(), int(ready.size()), timeout_ms);
      if (stop) break;
      auto now = Clock::now();
      stepped.clear();
      for (int i = 0; i < std::max(n, 0); ++i) {
        uint64_t key = ready[size_t(i)].data.u64;
        if (key == kWakeKey) continue;
        if (key & kListenerKey) {
          accept_tls(listeners[size_t(key & 0xFFFFFFFF)], now);
          continue;
        }
        auto* w = reinterpret_cast<Watch*>(uintptr_t(key));
        Pipe& p = *w->pipe;
        if (p.doomed || p.queued) continue;
        p.queued = true;
        stepped.push_back(&p);
      }
      for (Pipe* p : stepped) {
        p->queued = false;
        if (!p->doomed) shake(*p);
      }
      // Handshakes past their time limit.
      while (!handshakes.empty() && now - handshakes.front()->started > kHandshakeLimit) doom(door, *handshakes.front());
      bury(door);
    }
  }

  // ---- the relay: established connections ----

  // A connection the door handed over: its plain side (server side, from
  // `inner`), within the established connections' share of descriptors.
  void adopt(Pipe& p) {
    while (relay.fds_used + kFdsPerConnection > relay.fd_budget && make_room(&p)) {
    }
    relay.fds_used += kFdsPerConnection - (p.plain < 0 ? 2 : 0);  // the socketpair: counted when made
    if (p.plain < 0) {
      p.plain = p.inner ? p.inner(p.info) : -1;
      if (p.plain < 0) {
        ERR_clear_error();
        SSL_shutdown(p.ssl);
        ERR_clear_error();
        doom(relay, p);
        return;
      }
      relay.fds_used += kFdsPerConnection - 1;
      set_nonblocking(p.plain);
    }
    step(p);
    if (p.done) doom(relay, p);
    else update(relay, p);
  }

  // Does everything that can be done without blocking.
  void step(Pipe& p) {
    if (p.done || !p.ssl) return;
    // TLS -> plain
    while (!p.tls_eof && p.to_plain.size() < kBufferBound) {
      char buf[4096];
      ERR_clear_error();
      int n = SSL_read(p.ssl, buf, sizeof buf);
      if (n > 0) {
        p.to_plain.append(buf, size_t(n));
        continue;
      }
      int e = SSL_get_error(p.ssl, n);
      ERR_clear_error();
      if (e == SSL_ERROR_WANT_READ) break;
      if (e == SSL_ERROR_WANT_WRITE) {
        p.want_write = true;
        break;
      }
      // SSL_ERROR_ZERO_RETURN: close_notify; anything else (a FIN without
      // close_notify, a reset): this connection is gone, and only this one.
      p.tls_eof = true;
      if (e != SSL_ERROR_ZERO_RETURN) {
        p.done = true;
        return;
      }
    }
    while (!p.to_plain.empty()) {
      ssize_t n = ::send(p.plain, p.to_plain.data(), p.to_plain.size(), MSG_NOSIGNAL);
      if (n > 0) {
        p.to_plain.erase(0, size_t(n));
        continue;
      }
      if (n < 0 && (errno == EAGAIN || errno == EINTR)) break;
      p.done = true;
      return;
    }
    // The TLS peer closed its side: so does the plain side (the replies to
    // what it sent still come back).
    if (p.tls_eof && p.to_plain.empty()) ::shutdown(p.plain, SHUT_WR);
    // plain -> TLS
    while (!p.plain_eof && p.to_tls.size() < kBufferBound) {
      char buf[4096];
      ssize_t n = ::recv(p.plain, buf, sizeof buf, 0);
      if (n > 0) {
        p.to_tls.append(buf, size_t(n));
        continue;
      }
      if (n < 0 && (errno == EAGAIN || errno == EINTR)) break;
      p.plain_eof = true;
    }
    p.want_write = false;
    while (!p.to_tls.empty()) {
      ERR_clear_error();
      int n = SSL_write(p.ssl, p.to_tls.data(), int(p.to_tls.size()));
      if (n > 0) {
        p.to_tls.erase(0, size_t(n));
        continue;
      }
      int e = SSL_get_error(p.ssl, n);
      ERR_clear_error();
      if (e == SSL_ERROR_WANT_WRITE || e == SSL_ERROR_WANT_READ) {
        p.want_write = e == SSL_ERROR_WANT_WRITE;
        return;
      }
      p.done = true;
      return;
    }
    // The plain side ended and everything it said went out: close_notify.
    if (p.plain_eof) {
      ERR_clear_error();
      SSL_shutdown(p.ssl);
      ERR_clear_error();
      p.done = true;
    }
  }

  void run_relay() {
    NoSigpipe no_sigpipe;
    std::vector<epoll_event> ready(256);
    std::vector<Pipe*> stepped;
    while (!stop) {
      int n = epoll_wait(relay.epfd, ready.data(), int(ready.size()), 1000);
      if (stop) break;
      stepped.clear();
      bool woken = false;
      for (int i = 0; i < std::max(n, 0); ++i) {
        uint64_t key = ready[size_t(i)].data.u64;
        if (key == kWakeKey) {
          woken = true;
          continue;
        }
        auto* w = reinterpret_cast<Watch*>(uintptr_t(key));
        Pipe& p = *w->pipe;
        if (p.doomed || p.queued) continue;
        p.queued = true;
        stepped.push_back(&p);
      }
      for (Pipe* p : stepped) {
        p->queued = false;
        if (p->doomed) continue;
        step(*p);
        if (p->done) {
          doom(relay, *p);
          continue;
        }
        relay.pipes.splice(relay.pipes.end(), relay.pipes, p->self);  // used now: last in line for make_room
        update(relay, *p);
      }
      if (woken) {
        char buf[256];
        while (::read(relay.wake[0], buf, sizeof buf) > 0) {
        }
        std::list<Pipe> taken;
        {
          std::lock_guard<std::mutex> g(handoff_mutex);
          taken.splice(taken.end(), handoff);
        }
        while (!taken.empty()) {
          auto it = taken.begin();
          relay.pipes.splice(relay.pipes.end(), taken, it);
          adopt(*it);
        }
      }
      bury(relay);
    }
  }

  void run() {
    rlimit nofile{};
    getrlimit(RLIMIT_NOFILE, &nofile);
    size_t limit = nofile.rlim_cur == RLIM_INFINITY ? size_t(1) << 20 : size_t(nofile.rlim_cur);
    size_t budget = limit > 2 * kReservedFds ? limit - kReservedFds : limit / 2;
    // The handshakes' share: one descriptor each, at most a quarter.
    max_handshakes = std::max<size_t>(1, std::min(kMaxHandshakes, budget / 4));
    door.fd_budget = max_handshakes;
    relay.fd_budget = budget - max_handshakes;
    spare = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
    for (Loop* l : {&door, &relay}) {
      l->epfd = epoll_create1(EPOLL_CLOEXEC);
      if (l->epfd < 0) return;
      epoll_event e{};
      e.events = EPOLLIN;
      e.data.u64 = kWakeKey;
      epoll_ctl(l->epfd, EPOLL_CTL_ADD, l->wake[0], &e);
    }
    for (size_t i = 0; i < listeners.size(); ++i) {
      epoll_event e{};
      e.events = EPOLLIN;
      e.data.u64 = kListenerKey | i;
      epoll_ctl(door.epfd, EPOLL_CTL_ADD, listeners[i].fd, &e);
    }
    relay_thread = std::thread([this] { run_relay(); });
    door_thread = std::thread([this] { run_door(); });
  }
};

Relay::Relay() : impl_(std::make_unique<Impl>()) {
  for (Loop* l : {&impl_->door, &impl_->relay})
    if (pipe2(l->wake, O_CLOEXEC | O_NONBLOCK) != 0) throw std::runtime_error("pipe: " + strerr());
}
Relay::~Relay() = default;

std::string Relay::listen_tls(const std::string& host, uint16_t port, Ctx ctx, std::function<int(const Peer&)> inner) {
  std::string bound;
  int fd = listen_on(host, port, bound);
  impl_->listeners.push_back({fd, true, ctx.get(), std::move(inner), "", 0, 0});
  impl_->ctxs.push_back(std::move(ctx));
  return bound;
}

uint16_t Relay::listen_plain(const std::string& host, uint16_t port, Ctx ctx, int timeout_ms) {
  std::string bound;
  int fd = listen_on("127.0.0.1", 0, bound);
  impl_->listeners.push_back({fd, false, ctx.get(), nullptr, host, port, timeout_ms});
  impl_->ctxs.push_back(std::move(ctx));
  return uint16_t(std::stoi(bound.substr(bound.rfind(':') + 1)));
}

void Relay::start() { impl_->run(); }

std::string Relay::last_error() const {
  std::lock_guard<std::mutex> g(impl_->error_mutex);
  return impl_->last_error;
}

}  // namespace mbc::tls
