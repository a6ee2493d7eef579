# The OSS-Fuzz / ClusterFuzzLite build (fuzz/build.sh, .clusterfuzzlite/),
# run as those engines run it. Only in the libFuzzer build (-DMBCONFORM_FUZZ=ON,
# clang), whose `ctest -L fuzz` .ci/run runs: not in the README's test command.
if(MBCONFORM_FUZZ)
  add_test(NAME oss_fuzz_build
    COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/ossfuzz_build_test.sh ${CMAKE_SOURCE_DIR} ${CMAKE_BINARY_DIR}/oss-fuzz)
  # Beside the smoke tests, not alone: they fuzz for a fixed time whatever the load.
  set_tests_properties(oss_fuzz_build PROPERTIES LABELS "fuzz;ossfuzz" TIMEOUT 3600)
endif()
