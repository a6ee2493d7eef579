#!/bin/bash -eu
# ClusterFuzzLite runs this with OSS-Fuzz's environment ($CC $CXX $CFLAGS
# $CXXFLAGS $LIB_FUZZING_ENGINE $OUT $SRC $WORK): the build script is the
# OSS-Fuzz one, fuzz/build.sh, which the ctest oss_fuzz_build runs the same way.
exec "$SRC/mbconform/fuzz/build.sh"
