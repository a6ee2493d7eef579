// pcap / pcapng (libpcap) and serial logs into Modbus frames. TCP is
// reassembled by the code below rather than by libtins: README.md says why.
#include <pcap/pcap.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <memory>
#include <string>
#include <unordered_map>

#include "capture/frames.h"
#include "capture/serial_log.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"
#include "modbus/limits.h"
#include "modbus/mbap.h"
#include "modbus/rtu.h"
#include "modbus/text.h"

namespace mbc::conf::capture {
namespace {

// LINKTYPE_USER0 as mbconform writes it: one header byte, the direction.
constexpr int kUser0 = 147;

struct Address {
  std::array<uint8_t, 16> bytes{};
  uint8_t family = 4;
  bool operator==(const Address&) const = default;
  std::string text() const {
    if (family == 4) return strf("%u.%u.%u.%u", bytes[0], bytes[1], bytes[2], bytes[3]);
    std::string s;
    for (int i = 0; i < 16; i += 2) s += strf(i ? ":%x" : "%x", unsigned(bytes[i] << 8 | bytes[i + 1]));
    return "[" + s + "]";
  }
};

// A conversation, keyed server side first.
struct Key {
  Address server, client;
  uint16_t server_port = 0, client_port = 0;
  bool udp = false;
  bool operator==(const Key&) const = default;
};
struct KeyHash {
  size_t operator()(const Key& k) const {
    size_t h = 1469598103934665603ull;
    auto mix = [&](uint8_t b) { h = (h ^ b) * 1099511628211ull; };
    for (auto b : k.server.bytes) mix(b);
    for (auto b : k.client.bytes) mix(b);
    mix(uint8_t(k.server_port)), mix(uint8_t(k.server_port >> 8)), mix(uint8_t(k.client_port)),
        mix(uint8_t(k.client_port >> 8)), mix(k.udp);
    return h;
  }
};

// One direction of a TCP conversation: where its byte stream has got to and
// the bytes of an ADU not yet whole (at most one ADU's worth is kept).
struct Direction_ {
  bool started = false;
  uint32_t next = 0;
  Bytes pending;
  bool fin = false;
};

struct Stream {
  uint32_t id = 0;
  std::string name;
  uint64_t last_packet = 0;
  std::optional<Carrier> carrier;
  Direction_ dir[2];  // [0] client -> server, [1] server -> client
};

constexpr uint8_t kFin = 0x01, kSyn = 0x02, kRst = 0x04;

class Reader {
 public:
  Reader(const ReadOptions& o, FrameSink& sink, ReadStats& st) : opt_(o), sink_(sink), st_(st) {}

  void packet(int linktype, uint64_t time_us, std::span<const uint8_t> data) {
    ++st_.packets;
    now_ = time_us;
    switch (linktype) {
      case DLT_EN10MB: ethernet(data); break;
      case DLT_RAW: case 228: case 229: ip(data); break;  // raw IPv4, IPv6
      case DLT_NULL: case DLT_LOOP:
        if (data.size() >= 4) ip(data.subspan(4));
        break;
      case DLT_LINUX_SLL:
        if (data.size() >= 16) ether_type(be16(data, 14), data.subspan(16));
        break;
      case 276:  // LINUX_SLL2
        if (data.size() >= 20) ether_type(be16(data, 0), data.subspan(20));
        break;
      case kUser0: user0(data); break;
      default:
        if (st_.packets == 1) note(strf("link type %d is not read (Ethernet, raw IP, Linux cooked, loopback, USER0 RTU are)", linktype));
    }
  }

  void finish() {
    for (auto& [k, s] : streams_) end(s, "the capture ends");
    streams_.clear();
    if (user0_started_) sink_.stream_end(user0_id_);
  }

 private:
  void note(std::string what) { sink_.finding({st_.packets, std::move(what)}); }

  void ethernet(std::span<const uint8_t> d) {
    if (d.size() < 14) return note("Ethernet frame shorter than its header");
    size_t at = 12;
    uint16_t type = be16(d, at);
    while ((type == 0x8100 || type == 0x88A8) && d.size() >= at + 6) {  // VLAN tags
      at += 4;
      type = be16(d, at);
    }
    ether_type(type, d.subspan(at + 2));
  }
  void ether_type(uint16_t type, std::span<const uint8_t> d) {
    if (type == 0x0800 || type == 0x86DD) ip(d);
  }

  void ip(std::span<const uint8_t> d) {
    if (d.empty()) return;
    Address src, dst;
    uint8_t proto = 0;
    std::span<const uint8_t> payload;
    if ((d[0] >> 4) == 4) {
      size_t ihl = size_t(d[0] & 0x0F) * 4;
      if (d.size() < 20 || ihl < 20 || d.size() < ihl) return note("IPv4 header truncated");
      size_t total = be16(d, 2);
      if (total < ihl) return note("IPv4 total length shorter than its header");
      if (total > d.size()) {
        note(strf("IPv4 packet cut short: %zu of %zu bytes captured", d.size(), total));
        total = d.size();
      }
      if ((be16(d, 6) & 0x3FFF) != 0) return note("IPv4 fragment: fragments are not reassembled");
      proto = d[9];
      std::copy_n(d.begin() + 12, 4, src.bytes.begin());
      std::copy_n(d.begin() + 16, 4, dst.bytes.begin());
      payload = d.subspan(ihl, total - ihl);  // Ethernet padding dropped
    } else if ((d[0] >> 4) == 6) {
      if (d.size() < 40) return note("IPv6 header truncated");
      src.family = dst.family = 6;
      std::copy_n(d.begin() + 8, 16, src.bytes.begin());
      std::copy_n(d.begin() + 24, 16, dst.bytes.begin());
      size_t len = std::min<size_t>(be16(d, 4), d.size() - 40);
      proto = d[6];
      payload = d.subspan(40, len);
      for (int hops = 0; hops < 8 && (proto == 0 || proto == 43 || proto == 60); ++hops) {
        if (payload.size() < 8) return;
        size_t ext = (size_t(payload[1]) + 1) * 8;
        if (payload.size() < ext) return;
        proto = payload[0];
        payload = payload.subspan(ext);
      }
      if (proto == 44) return note("IPv6 fragment: fragments are not reassembled");
    } else {
      return;
    }
    if (proto == 6) tcp(src, dst, payload);
    else if (proto == 17) udp(src, dst, payload);
  }

  bool server_port(uint16_t p) const { return std::find(opt_.ports.begin(), opt_.ports.end(), p) != opt_.ports.end(); }

  // The conversation of a segment, server side first; nullptr when neither
  // port is a server port.
  Stream* stream(const Address& src, const Address& dst, uint16_t sport, uint16_t dport, bool udp, bool& to_server) {
    Key k;
    k.udp = udp;
    if (server_port(dport)) {
      to_server = true;
      k = {dst, src, dport, sport, udp};
    } else if (server_port(sport)) {
      to_server = false;
      k = {src, dst, sport, dport, udp};
    } else {
      return nullptr;
    }
    auto it = streams_.find(k);
    if (it == streams_.end()) {
      if (streams_.size() >= opt_.max_streams) evict();
      Stream s;
      s.id = next_stream_++;
      s.name = strf("%s:%u -> %s:%u%s", k.client.text().c_str(), k.client_port, k.server.text().c_str(), k.server_port,
                    udp ? " (UDP)" : "");
      ++st_.streams;
      it = streams_.emplace(k, std::move(s)).first;
    }
    it->second.last_packet = st_.packets;
    return &it->second;
  }

  // The eighth of the conversations idle the longest.
  void evict() {
    std::vector<std::pair<uint64_t, Key>> ages;
    ages.reserve(streams_.size());
    for (const auto& [k, s] : streams_) ages.emplace_back(s.last_packet, k);
    size_t drop = std::max<size_t>(1, ages.size() / 8);
    std::nth_element(ages.begin(), ages.begin() + ptrdiff_t(drop - 1), ages.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    for (size_t i = 0; i < drop; ++i) {
      auto it = streams_.find(ages[i].second);
      end(it->second, strf("more than %zu conversations open at once: the one idle the longest is dropped", opt_.max_streams));
      streams_.erase(it);
    }
  }

  void end(Stream& s, const char* why) { end(s, std::string(why)); }
  void end(Stream& s, const std::string& why) {
    for (int d = 0; d < 2; ++d)
      if (!s.dir[d].pending.empty()) {
        note(strf("%s: %zu bytes of an incomplete %s left when %s", s.name.c_str(), s.dir[d].pending.size(),
                  d == 0 ? "request" : "reply", why.c_str()));
        s.dir[d].pending.clear();
      }
    sink_.stream_end(s.id);
  }

  void tcp(const Address& src, const Address& dst, std::span<const uint8_t> d) {
    if (d.size() < 20) return note("TCP header truncated");
    size_t off = size_t(d[12] >> 4) * 4;
    if (off < 20 || off > d.size()) return note("TCP data offset out of the segment");
    uint16_t sport = be16(d, 0), dport = be16(d, 2);
    uint32_t seq = uint32_t(d[4]) << 24 | uint32_t(d[5]) << 16 | uint32_t(d[6]) << 8 | d[7];
    uint8_t flags = d[13];
    bool to_server = true;
    Stream* s = stream(src, dst, sport, dport, false, to_server);
    if (!s) return;
    Direction_& x = s->dir[to_server ? 0 : 1];
    auto payload = d.subspan(off);
    if (flags & kSyn) {
      x.started = true;
      x.next = seq + 1;
      seq += 1;
    }
    if (!payload.empty()) segment(*s, to_server, seq, payload);
    if (flags & kRst) return close(*s, "the connection was reset");
    if (flags & kFin) {
      x.fin = true;
      if (s->dir[0].fin && s->dir[1].fin) close(*s, "the connection closed");
    }
  }

  void close(Stream& s, const char* why) {
    end(s, why);
    for (auto it = streams_.begin(); it != streams_.end(); ++it)
      if (&it->second == &s) {
        streams_.erase(it);
        return;
      }
  }

  // The byte stream's rules: a segment that starts where the stream got to
  // is appended; one that starts earlier repeats what was seen (a
  // retransmission; only bytes past the stream's end are new); one that starts
  // later leaves a hole (segments not captured): the ADU being assembled is
  // lost and reading starts again at this segment.
  void segment(Stream& s, bool to_server, uint32_t seq, std::span<const uint8_t> payload) {
    Direction_& x = s.dir[to_server ? 0 : 1];
    if (!x.started) {
      x.started = true;
      x.next = seq;
    }
    int32_t diff = int32_t(seq - x.next);
    if (diff < 0) {
      uint32_t seen = uint32_t(-int64_t(diff));
      if (seen >= payload.size()) return;  // retransmission
      payload = payload.subspan(seen);
      seq = x.next;
    } else if (diff > 0) {
      if (!x.pending.empty())
        note(strf("%s: %u bytes not captured: %zu bytes of an incomplete %s dropped", s.name.c_str(), uint32_t(diff),
                  x.pending.size(), to_server ? "request" : "reply"));
      x.pending.clear();
    }
    x.next = seq + uint32_t(payload.size());
    x.pending.insert(x.pending.end(), payload.begin(), payload.end());
    extract(s, to_server, x.pending);
  }

  void emit(Stream& s, bool to_server, Carrier c, std::span<const uint8_t> adu, bool timed = false) {
    Frame f;
    f.time_us = now_;
    f.packet = st_.packets;
    f.stream = s.id;
    f.conversation = s.name;
    f.to_server = to_server;
    f.carrier = c;
    f.timed_line = timed;
    f.adu.assign(adu.begin(), adu.end());
    ++st_.frames;
    sink_.frame(f);
  }

  static bool mbap_header_ok(std::span<const uint8_t> b) {
    return b.size() >= 8 && be16(b, 2) == 0 && be16(b, 4) >= 2 && be16(b, 4) <= 1 + kMaxPdu;
  }

  // The length of the RTU frame at the start of `b`, when its function code
  // or byte count fixes it, else the first length whose CRC checks.
  static std::optional<size_t> rtu_length(std::span<const uint8_t> b, bool to_server) {
    auto n = rtu_adu_length(b, to_server ? Direction::request : Direction::reply);
    if (n) return *n <= b.size() ? n : std::nullopt;
    for (size_t k = 4; k <= std::min(b.size(), kMaxRtuAdu); ++k)
      if (crc_ok(b.first(k))) return k;
    return std::nullopt;
  }

  void extract(Stream& s, bool to_server, Bytes& buf) {
    size_t at = 0;
    while (at < buf.size()) {
      std::span<const uint8_t> rest(buf.data() + at, buf.size() - at);
      if (!s.carrier) {
        // Told apart once per conversation: an RTU frame whose CRC checks
        // (RTU over TCP), else an MBAP header. The CRC first: a common RTU
        // request looks like an MBAP header ("01 03 00 00 00 0A C5 CD":
        // protocol 0, length 10), while an MBAP ADU whose first bytes end in
        // a CRC that checks is a chance of 1 in 65536.
        if (rest.size() < 8) break;
        if (auto n = rtu_length(rest, to_server); n && crc_ok(rest.first(*n))) {
          s.carrier = Carrier::rtu;
        } else if (mbap_header_ok(rest)) {
          s.carrier = Carrier::mbap;
        } else if (rest.size() >= kMaxRtuAdu || rest.size() >= 8) {
          note(strf("%s: %zu bytes that are neither an MBAP header (protocol %u, length %u) nor an RTU frame with a "
                    "good CRC: skipped",
                    s.name.c_str(), rest.size(), be16(rest, 2), be16(rest, 4)));
          at = buf.size();
          break;
        }
      }
      if (s.carrier == Carrier::mbap) {
        if (rest.size() < 8) break;
        if (!mbap_header_ok(rest)) {
          // Wireshark's rule too: protocol 0 and a length of at least unit +
          // function code, else the rest of the segment is not Modbus.
          note(strf("%s: not Modbus/TCP (protocol %u, length %u): %zu bytes skipped", s.name.c_str(), be16(rest, 2),
                    be16(rest, 4), rest.size()));
          at = buf.size();
          break;
        }
        size_t need = 6 + size_t(be16(rest, 4));
        if (rest.size() < need) break;
        emit(s, to_server, Carrier::mbap, rest.first(need));
        at += need;
      } else {
        auto n = rtu_length(rest, to_server);
        if (!n) {
          if (rest.size() >= kMaxRtuAdu) {
            note(strf("%s: %zu bytes with no RTU frame whose CRC checks: skipped", s.name.c_str(), rest.size()));
            at = buf.size();
          }
          break;
        }
        emit(s, to_server, Carrier::rtu, rest.first(*n));
        at += *n;
      }
    }
    buf.erase(buf.begin(), buf.begin() + ptrdiff_t(at));
  }

  void udp(const Address& src, const Address& dst, std::span<const uint8_t> d) {
    if (d.size() < 8) return note("UDP header truncated");
    bool to_server = true;
    Stream* s = stream(src, dst, be16(d, 0), be16(d, 2), true, to_server);
    if (!s) return;
    auto payload = d.subspan(8, std::min<size_t>(d.size(), be16(d, 4)) - std::min<size_t>(8, be16(d, 4)));
    if (payload.size() >= 4 && crc_ok(payload))  // an RTU frame first, as for TCP
      emit(*s, to_server, Carrier::rtu, payload);
    else if (mbap_header_ok(payload) && payload.size() == 6 + size_t(be16(payload, 4)))
      emit(*s, to_server, Carrier::mbap, payload);
    else if (!payload.empty())
      note(strf("%s: a %zu-byte datagram that is neither one MBAP ADU nor one RTU frame", s->name.c_str(), payload.size()));
  }

  // mbconform's own RTU captures: one direction byte, then the ADU.
  void user0(std::span<const uint8_t> d) {
    if (d.size() < 2) return note("USER0 packet shorter than its direction byte and a frame");
    if (!user0_started_) {
      user0_started_ = true;
      user0_id_ = next_stream_++;
      ++st_.streams;
    }
    Stream s;
    s.id = user0_id_;
    s.name = "RTU line";
    emit(s, d[0] == 0, Carrier::rtu, d.subspan(1));
  }

  const ReadOptions& opt_;
  FrameSink& sink_;
  ReadStats& st_;
  uint64_t now_ = 0;
  uint32_t next_stream_ = 0;
  bool user0_started_ = false;
  uint32_t user0_id_ = 0;
  std::unordered_map<Key, Stream, KeyHash> streams_;
};

ReadStats read_pcap(FILE* f, bool ng, const ReadOptions& o, FrameSink& sink) {
  ReadStats st;
  st.format = ng ? "pcapng" : "pcap";
  char err[PCAP_ERRBUF_SIZE] = {};
  pcap_t* p = pcap_fopen_offline_with_tstamp_precision(f, PCAP_TSTAMP_PRECISION_MICRO, err);
  if (!p) {
    std::fclose(f);
    st.error = err[0] ? err : "not a capture libpcap can read";
    return st;
  }
  std::unique_ptr<pcap_t, void (*)(pcap_t*)> guard(p, pcap_close);
  Reader r(o, sink, st);
  int linktype = pcap_datalink(p);
  pcap_pkthdr* h = nullptr;
  const u_char* data = nullptr;
  for (;;) {
    int rc = pcap_next_ex(p, &h, &data);
    if (rc == PCAP_ERROR_BREAK) break;  // end of file
    if (rc != 1) {
      st.error = strf("stopped after packet %llu: %s", static_cast<unsigned long long>(st.packets), pcap_geterr(p));
      break;
    }
    st.bytes += h->caplen + 16;
    uint64_t t = uint64_t(h->ts.tv_sec) * 1000000u + uint64_t(h->ts.tv_usec);
    r.packet(linktype, t, std::span(data, h->caplen));
  }
  r.finish();
  return st;
}

bool is_capture_magic(const uint8_t* m) {
  static const uint8_t magics[][4] = {{0xD4, 0xC3, 0xB2, 0xA1}, {0xA1, 0xB2, 0xC3, 0xD4}, {0x4D, 0x3C, 0xB2, 0xA1},
                                      {0xA1, 0xB2, 0x3C, 0x4D}, {0x0A, 0x0D, 0x0D, 0x0A}};
  for (const auto& x : magics)
    if (std::memcmp(m, x, 4) == 0) return true;
  return false;
}

ReadStats read_any(FILE* f, const ReadOptions& o, FrameSink& sink) {
  uint8_t magic[4] = {};
  size_t n = std::fread(magic, 1, 4, f);
  std::rewind(f);
  if (n == 0) {
    std::fclose(f);
    ReadStats st;
    st.error = "empty file";
    return st;
  }
  if (n == 4 && is_capture_magic(magic)) return read_pcap(f, magic[0] == 0x0A, o, sink);
  ReadStats st = read_serial_log(f, sink);
  std::fclose(f);
  return st;
}

}  // namespace

ReadStats read_capture(const std::string& path, const ReadOptions& o, FrameSink& sink) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) {
    ReadStats st;
    st.error = strf("cannot open %s: %s", path.c_str(), std::strerror(errno));
    return st;
  }
  return read_any(f, o, sink);
}

ReadStats read_capture_bytes(std::span<const uint8_t> data, const ReadOptions& o, FrameSink& sink) {
  static const uint8_t empty = 0;
  FILE* f = fmemopen(const_cast<uint8_t*>(data.empty() ? &empty : data.data()), std::max<size_t>(data.size(), 1), "rb");
  if (!f) {
    ReadStats st;
    st.error = "cannot read the bytes given";
    return st;
  }
  if (data.empty()) {
    ReadStats st;
    st.error = "empty input";
    std::fclose(f);
    return st;
  }
  return read_any(f, o, sink);
}

}  // namespace mbc::conf::capture
