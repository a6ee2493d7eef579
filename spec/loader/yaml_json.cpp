#include "yaml_json.h"

#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/parser.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <sstream>
#include <vector>

namespace mbc::spec {
namespace {

using nlohmann::json;

std::string escape_pointer_token(const std::string& s) {
  std::string r;
  for (char c : s) {
    if (c == '~') r += "~0";
    else if (c == '/') r += "~1";
    else r += c;
  }
  return r;
}

// Plain YAML scalars get the YAML 1.2 core schema's types; quoted ones stay strings.
json plain_scalar(const std::string& s) {
  if (s.empty() || s == "~" || s == "null" || s == "Null" || s == "NULL") return nullptr;
  if (s == "true" || s == "True" || s == "TRUE") return true;
  if (s == "false" || s == "False" || s == "FALSE") return false;
  const char* b = s.data();
  const char* e = s.data() + s.size();
  bool neg = false;
  const char* p = b;
  if (*p == '-' || *p == '+') {
    neg = *p == '-';
    ++p;
  }
  if (p < e) {
    int base = 10;
    if (e - p > 2 && p[0] == '0' && (p[1] == 'x' || p[1] == 'X')) {
      base = 16;
      p += 2;
    } else if (e - p > 2 && p[0] == '0' && p[1] == 'o') {
      base = 8;
      p += 2;
    }
    uint64_t v = 0;
    auto [q, ec] = std::from_chars(p, e, v, base);
    if (ec == std::errc() && q == e) {
      if (!neg && v <= uint64_t(INT64_MAX)) return int64_t(v);
      if (neg && v <= uint64_t(INT64_MAX) + 1) return v == uint64_t(INT64_MAX) + 1 ? INT64_MIN : -int64_t(v);
      return s;  // out of range: the schema reports a string where a number belongs
    }
    if (ec == std::errc::result_out_of_range) return s;
  }
  // Floats need a dot ("1.5", "2.5e3"), as in YAML 1.1: "8E1" is a frame
  // format, not 80.
  bool digit = false, bad = s.find('.') == std::string::npos;
  for (const char* c = b; c < e && !bad; ++c) {
    if (std::isdigit(static_cast<unsigned char>(*c))) digit = true;
    else if (!(*c == '.' || *c == 'e' || *c == 'E' || *c == '-' || *c == '+')) bad = true;
  }
  if (digit && !bad) {
    double d = 0;
    auto [q, ec] = std::from_chars(b + (*b == '+'), e, d);
    if (ec == std::errc() && q == e && std::isfinite(d)) return d;
  }
  return s;
}

struct Converter {
  const std::string& file;
  const YamlLimits& limits;
  JsonDocument& doc;
  Diagnostics& out;
  size_t nodes = 0;

  bool fail(const YAML::Mark& m, const std::string& msg) {
    out.push_back({file, m.line + 1, m.column + 1, "yaml", msg});
    return false;
  }

  bool convert(const YAML::Node& node, const std::string& pointer, int depth, json& into) {
    if (++nodes > limits.max_nodes) return fail(node.Mark(), "document too large (too many nodes, or aliases expanding too far)");
    if (depth > limits.max_depth) return fail(node.Mark(), "nesting deeper than " + std::to_string(limits.max_depth) + " levels");
    doc.locations.emplace(pointer, SourceLoc{node.Mark().line + 1, node.Mark().column + 1});
    switch (node.Type()) {
      case YAML::NodeType::Undefined:
      case YAML::NodeType::Null:
        into = nullptr;
        return true;
      case YAML::NodeType::Scalar: {
        const std::string& s = node.Scalar();
        if (s.size() > limits.max_scalar_bytes)
          return fail(node.Mark(), "scalar longer than " + std::to_string(limits.max_scalar_bytes) + " bytes");
        into = node.Tag() == "!" ? json(s) : plain_scalar(s);
        return true;
      }
      case YAML::NodeType::Sequence: {
        into = json::array();
        size_t i = 0;
        for (const auto& item : node) {
          json v;
          if (!convert(item, pointer + "/" + std::to_string(i++), depth + 1, v)) return false;
          into.push_back(std::move(v));
        }
        return true;
      }
      case YAML::NodeType::Map: {
        into = json::object();
        for (const auto& kv : node) {
          if (!kv.first.IsScalar()) return fail(kv.first.Mark(), "mapping keys must be plain scalars");
          const std::string& key = kv.first.Scalar();
          if (key.size() > 200) return fail(kv.first.Mark(), "mapping key longer than 200 bytes");
          if (into.contains(key)) return fail(kv.first.Mark(), "duplicate key '" + key + "'");
          json v;
          if (!convert(kv.second, pointer + "/" + escape_pointer_token(key), depth + 1, v)) return false;
          into[key] = std::move(v);
        }
        return true;
      }
    }
    return true;
  }
};

}  // namespace

SourceLoc JsonDocument::where(const std::string& pointer) const {
  std::string p = pointer;
  for (;;) {
    auto it = locations.find(p);
    if (it != locations.end()) return it->second;
    if (p.empty()) return {1, 1};
    auto slash = p.rfind('/');
    p = slash == std::string::npos ? std::string() : p.substr(0, slash);
  }
}

// Offset of the first byte that is not well-formed UTF-8 (Unicode 15 Table
// 3-7: no overlongs, no surrogates, nothing past U+10FFFF), or npos. A spec is
// UTF-8 text (YAML 1.2 §5.2); bytes that are not would reach the JSON Schema
// validator's string functions, which assume valid UTF-8 (fuzz/README.md).
// Counts documents without building them (the event handler ignores events).
// Counts the documents of a stream, and bounds its nesting as it is parsed.
// yaml-cpp's parser recurses once per nesting level, and announces each
// collection (OnSequenceStart, OnMapStart) before it descends into it: so
// throwing there stops the parse max_depth levels down, whatever the text
// hides its brackets behind (multi-line strings, plain scalars holding
// quotes). A guess from the raw text could be fooled; the parser cannot.
struct DocumentCounter final : YAML::EventHandler {
  explicit DocumentCounter(int max) : max_depth(max) {}
  int max_depth, depth = 0;
  void enter(const YAML::Mark& at) {
    if (++depth > max_depth) throw YAML::ParserException(at, "nesting deeper than " + std::to_string(max_depth) + " levels");
  }
  void OnDocumentStart(const YAML::Mark&) override { depth = 0; }
  void OnDocumentEnd() override {}
  void OnNull(const YAML::Mark&, YAML::anchor_t) override {}
  void OnAlias(const YAML::Mark&, YAML::anchor_t) override {}
  void OnScalar(const YAML::Mark&, const std::string&, YAML::anchor_t, const std::string&) override {}
  void OnSequenceStart(const YAML::Mark& at, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override { enter(at); }
  void OnSequenceEnd() override { --depth; }
  void OnMapStart(const YAML::Mark& at, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override { enter(at); }
  void OnMapEnd() override { --depth; }
};

static size_t first_invalid_utf8(std::string_view t) {
  size_t i = 0;
  while (i < t.size()) {
    unsigned char c = uint8_t(t[i]);
    size_t n = c < 0x80 ? 0 : (c >= 0xC2 && c <= 0xDF) ? 1 : (c >= 0xE0 && c <= 0xEF) ? 2 : (c >= 0xF0 && c <= 0xF4) ? 3 : 99;
    if (n == 99 || i + n >= t.size() + (n ? 0 : 1)) return i;
    unsigned char c1 = n ? uint8_t(t[i + 1]) : 0;
    unsigned char lo = 0x80, hi = 0xBF;
    if (c == 0xE0) lo = 0xA0;
    if (c == 0xED) hi = 0x9F;
    if (c == 0xF0) lo = 0x90;
    if (c == 0xF4) hi = 0x8F;
    if (n && (c1 < lo || c1 > hi)) return i;
    for (size_t k = 2; k <= n; ++k)
      if ((uint8_t(t[i + k]) & 0xC0) != 0x80) return i;
    i += n + 1;
  }
  return std::string_view::npos;
}

std::optional<JsonDocument> yaml_to_json(std::string_view text, const std::string& file,
                                         Diagnostics& out, const YamlLimits& limits) {
  if (text.size() > limits.max_bytes) {
    out.push_back({file, 1, 1, "yaml", "file larger than " + std::to_string(limits.max_bytes) + " bytes"});
    return std::nullopt;
  }
  if (text.find('\0') != std::string_view::npos) {
    out.push_back({file, 1, 1, "yaml", "file contains NUL bytes (not a text file)"});
    return std::nullopt;
  }
  if (size_t bad = first_invalid_utf8(text); bad != std::string_view::npos) {
    int line = 1 + int(std::count(text.begin(), text.begin() + long(bad), '\n'));
    size_t nl = text.rfind('\n', bad == 0 ? 0 : bad - 1);
    int col = int(bad - (nl == std::string_view::npos || bad == 0 ? 0 : nl + 1)) + 1;
    out.push_back({file, line, col, "yaml", "not UTF-8 text (YAML 1.2 §5.2): invalid byte sequence"});
    return std::nullopt;
  }
  YAML::Node root;
  try {
    // Documents are counted with a bounded loop, not YAML::LoadAll: yaml-cpp
    // 0.7's LoadAll never ends on some malformed streams (a stray ',' at the
    // top: jbeder/yaml-cpp#1040, fixed upstream by PR #1319), allocating a null
    // document per turn (found by spec_loader_fuzzer: ", a" hung the loader).
    std::istringstream stream{std::string(text)};
    YAML::Parser parser(stream);
    DocumentCounter counter(limits.max_depth);
    int docs = 0;
    while (docs < 2 && parser.HandleNextDocument(counter)) ++docs;
    if (docs == 0) {
      out.push_back({file, 1, 1, "yaml", "empty document"});
      return std::nullopt;
    }
    if (docs > 1) {
      out.push_back({file, 1, 1, "yaml", "more than one YAML document in the file (or a ',' outside a flow collection)"});
      return std::nullopt;
    }
    root = YAML::Load(std::string(text));
  } catch (const YAML::Exception& e) {
    out.push_back({file, e.mark.line + 1, e.mark.column + 1, "yaml", e.msg});
    return std::nullopt;
  } catch (const std::exception& e) {
    out.push_back({file, 1, 1, "yaml", e.what()});
    return std::nullopt;
  }
  JsonDocument doc;
  Converter conv{file, limits, doc, out};
  try {
    if (!conv.convert(root, "", 0, doc.root)) return std::nullopt;
  } catch (const std::exception& e) {
    out.push_back({file, 1, 1, "yaml", e.what()});
    return std::nullopt;
  }
  return doc;
}

}  // namespace mbc::spec
