# -DMBCONFORM_SANITIZE=ON builds everything under ASan and UBSan (one CI
# configuration runs the whole test suite this way).
option(MBCONFORM_SANITIZE "Build with AddressSanitizer and UndefinedBehaviorSanitizer" OFF)
if(MBCONFORM_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
  # Executables not position-independent: a PIE carries one relative
  # relocation per pointer in its data (2.3 million in mbconform under ASan),
  # all applied at every start; the suite starts the binaries thousands of
  # times (mbconform --version: 460 ms of CPU as a PIE, 300 ms without).
  add_link_options($<$<STREQUAL:$<TARGET_PROPERTY:TYPE>,EXECUTABLE>:-no-pie>)
  # With optimisation, GCC's -Wmaybe-uninitialized reports false positives
  # inside libstdc++ (std::regex's std::function states) once ASan instruments
  # the code; the Release build keeps the warning.
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    add_compile_options(-Wno-maybe-uninitialized)
  endif()
endif()
