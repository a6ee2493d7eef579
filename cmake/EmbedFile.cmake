# Writes OUT, a C++ source defining `std::string_view NAME()` holding IN's bytes.
file(READ "${IN}" content)
set(delim "mbc_embed")
file(WRITE "${OUT}" "// Generated from ${IN}; do not edit.\n#include <string_view>\nnamespace mbc::spec {\nstd::string_view ${NAME}() {\n  static constexpr std::string_view text = R\"${delim}(${content})${delim}\";\n  return text;\n}\n}  // namespace mbc::spec\n")
