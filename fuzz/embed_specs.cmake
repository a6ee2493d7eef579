# Writes OUT, a C++ source holding every spec/devices/*.yaml as text, so the
# harnesses carry the specs they were built from (an OSS-Fuzz runner has no
# source tree). Sorted by id, the order the harnesses' device selector uses.
file(GLOB specs "${SPEC_DIR}/devices/*.yaml")
list(SORT specs)
set(body "")
foreach(f IN LISTS specs)
  get_filename_component(id "${f}" NAME_WE)
  file(READ "${f}" content)
  string(APPEND body "  {\"${id}\", R\"mbc_spec_embed(${content})mbc_spec_embed\"},\n")
endforeach()
file(WRITE "${OUT}.tmp" "// Generated from spec/devices/*.yaml by fuzz/embed_specs.cmake; do not edit.\n#include \"fuzz_support.h\"\nnamespace mbc::fuzz {\nconst std::vector<EmbeddedSpec>& embedded_specs() {\n  static const std::vector<EmbeddedSpec> all = {\n${body}  };\n  return all;\n}\n}  // namespace mbc::fuzz\n")
execute_process(COMMAND ${CMAKE_COMMAND} -E copy_if_different "${OUT}.tmp" "${OUT}")
