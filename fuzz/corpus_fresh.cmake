# Regenerates the seed corpora and dictionaries into WORK_DIR and fails when
# they differ from the committed corpus/<harness>/ and fuzz/*_fuzzer.dict
# ("the committed corpus is stale"). corpus/regressions/ is kept by hand and
# not compared.
file(REMOVE_RECURSE "${WORK_DIR}")
execute_process(COMMAND "${GEN}" --out "${WORK_DIR}" --source "${SOURCE_DIR}" RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "mbc_corpus_gen failed (${rc})")
endif()
file(GLOB_RECURSE generated RELATIVE "${WORK_DIR}" "${WORK_DIR}/corpus/*" "${WORK_DIR}/fuzz/*.dict")
file(GLOB_RECURSE committed RELATIVE "${SOURCE_DIR}" "${SOURCE_DIR}/corpus/*" "${SOURCE_DIR}/fuzz/*_fuzzer.dict")
list(FILTER committed EXCLUDE REGEX "^corpus/regressions/")
list(FILTER committed EXCLUDE REGEX "^corpus/README")
# capture_fuzzer's seeds are third-party captures and its dictionary is
# pcap's own tokens: kept by hand, not generated from the specs.
list(FILTER committed EXCLUDE REGEX "^corpus/capture/")
list(FILTER committed EXCLUDE REGEX "^fuzz/capture_fuzzer.dict$")
list(SORT generated)
list(SORT committed)
if(NOT generated STREQUAL committed)
  set(missing ${generated})
  list(REMOVE_ITEM missing ${committed})
  set(extra ${committed})
  list(REMOVE_ITEM extra ${generated})
  message(FATAL_ERROR "the committed corpus is stale: not committed [${missing}], no longer generated [${extra}]; "
                      "run build/bin/mbc_corpus_gen --out . from the source root and commit")
endif()
foreach(f IN LISTS generated)
  execute_process(COMMAND ${CMAKE_COMMAND} -E compare_files "${WORK_DIR}/${f}" "${SOURCE_DIR}/${f}" RESULT_VARIABLE diff)
  if(NOT diff EQUAL 0)
    message(FATAL_ERROR "${f} is stale: the specs now generate something else; run build/bin/mbc_corpus_gen --out . and commit")
  endif()
endforeach()
