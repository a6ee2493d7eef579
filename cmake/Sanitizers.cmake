# -DMBCONFORM_SANITIZE=ON builds everything under ASan and UBSan (one CI
# configuration runs the whole test suite this way).
option(MBCONFORM_SANITIZE "Build with AddressSanitizer and UndefinedBehaviorSanitizer" OFF)
if(MBCONFORM_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
endif()
