// A problem found in a spec file, printed the way compilers print theirs:
//   spec/devices/x.yaml:12:5: error: register-overlap: 0x0010 is also ...
#pragma once

#include <string>
#include <vector>

namespace mbc::spec {

struct Diagnostic {
  std::string file;
  int line = 0;  // 1-based; 0 when the problem has no location (e.g. unreadable file)
  int col = 0;
  std::string rule;
  std::string message;

  std::string str() const;
};

using Diagnostics = std::vector<Diagnostic>;

}  // namespace mbc::spec
