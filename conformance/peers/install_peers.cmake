# cmake -DSRC=<conformance/peers> -DDST=<build>/peers -DNPM=<npm> -P install_peers.cmake
# Copies package.json and the committed lock file into DST and runs `npm ci`
# there, unless DST already holds an install of exactly this lock file.
# --omit=optional: modbus-stream's optional serialport 6 needs a native build
# that fails here (and would fetch prebuilt binaries); its TCP side needs none.
file(MAKE_DIRECTORY ${DST})
file(SHA256 ${SRC}/package-lock.json want)
if(EXISTS ${DST}/installed.sha256 AND EXISTS ${DST}/node_modules)
  file(READ ${DST}/installed.sha256 have)
  if(have STREQUAL want)
    message(STATUS "npm peers: up to date in ${DST}")
    return()
  endif()
endif()
file(COPY ${SRC}/package.json ${SRC}/package-lock.json DESTINATION ${DST})
execute_process(COMMAND ${NPM} ci --prefix ${DST} --omit=optional --no-audit --no-fund --loglevel=error
                RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "npm peers: `npm ci --prefix ${DST}` failed (${rc})")
endif()
file(WRITE ${DST}/installed.sha256 ${want})
message(STATUS "npm peers: installed into ${DST}/node_modules")
