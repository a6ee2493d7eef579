# Install rules and the Debian package (cpack -G DEB). Included last by the
# top-level CMakeLists.txt, so that optional targets (the plugin host, the
# client adapters) are known here.
#
#   cmake --install build --prefix P      P/bin/mbconform (stripped), P/share/mbconform/{devices,profiles,schema,
#                                         deviations,quirks}, the man page, the bash completion, ...
#   (cd build && cpack -G DEB)            build/mbconform_<version>_<arch>.deb
#
# An installed mbconform finds its specs in <bin>/../share/mbconform
# (spec/loader/spec_path.h), and `--quirks NAME` its libraries' declared
# deviations there (conformance/report/quirks.h), so the tree below may be
# moved as a whole.
include(GNUInstallDirs)
set(MBC_SHARE ${CMAKE_INSTALL_DATADIR}/mbconform)

# The install strips what it installs, as the .deb does (a 6 MB binary
# otherwise): cmake --install sets CMAKE_INSTALL_DO_STRIP only with --strip,
# so the install script sets it first. -DMBCONFORM_INSTALL_STRIP=OFF keeps
# the debug info (RelWithDebInfo, for a debugger).
option(MBCONFORM_INSTALL_STRIP "strip the executables cmake --install installs" ON)
if(MBCONFORM_INSTALL_STRIP)
  install(CODE "set(CMAKE_INSTALL_DO_STRIP TRUE)")
endif()

install(TARGETS mbconform RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
# The plugin host runs beside mbconform (conformance/targets/plugin_target.cpp).
if(TARGET mbconform-plugin-host)
  install(TARGETS mbconform-plugin-host RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
endif()

# The device specs and the language's schema.
install(DIRECTORY ${CMAKE_SOURCE_DIR}/spec/devices/ DESTINATION ${MBC_SHARE}/devices FILES_MATCHING PATTERN "*.yaml")
# The library control profiles a device names (`control: {profile: cia402}`),
# found in profiles/ beside devices/ (spec/loader/control.cpp).
install(DIRECTORY ${CMAKE_SOURCE_DIR}/spec/profiles/ DESTINATION ${MBC_SHARE}/profiles FILES_MATCHING PATTERN "*.yaml")
install(FILES ${CMAKE_SOURCE_DIR}/spec/schema/device.schema.json DESTINATION ${MBC_SHARE}/schema)

# The libraries' declared deviations, found by name (`--quirks libmodbus-tcp`):
# as masters (conformance/peers/deviations/, `mbconform client`) and as
# servers (conformance/peers/quirks/, `mbconform run`).
install(DIRECTORY ${CMAKE_SOURCE_DIR}/conformance/peers/deviations/ DESTINATION ${MBC_SHARE}/deviations
        FILES_MATCHING PATTERN "*.yaml" PATTERN "README.md")
install(DIRECTORY ${CMAKE_SOURCE_DIR}/conformance/peers/quirks/ DESTINATION ${MBC_SHARE}/quirks FILES_MATCHING PATTERN "*.yaml")

# The man page and the bash completion, written by the built mbconform from
# its own command definitions (tools/mbconform/manual.cpp), so they cannot
# drift from it.
set(mbc_man ${CMAKE_BINARY_DIR}/share/man/man1/mbconform.1)
set(mbc_bash ${CMAKE_BINARY_DIR}/share/bash-completion/completions/mbconform)
add_custom_command(OUTPUT ${mbc_man}
  COMMAND ${CMAKE_COMMAND} -DMBCONFORM=$<TARGET_FILE:mbconform> -DOUT=${mbc_man} "-DARGS=help;--man"
          -P ${CMAKE_SOURCE_DIR}/cmake/WriteManual.cmake
  DEPENDS mbconform ${CMAKE_SOURCE_DIR}/cmake/WriteManual.cmake VERBATIM)
add_custom_command(OUTPUT ${mbc_bash}
  COMMAND ${CMAKE_COMMAND} -DMBCONFORM=$<TARGET_FILE:mbconform> -DOUT=${mbc_bash} "-DARGS=completion;bash"
          -P ${CMAKE_SOURCE_DIR}/cmake/WriteManual.cmake
  DEPENDS mbconform ${CMAKE_SOURCE_DIR}/cmake/WriteManual.cmake VERBATIM)
add_custom_target(mbconform_manual ALL DEPENDS ${mbc_man} ${mbc_bash})
install(FILES ${mbc_man} DESTINATION ${CMAKE_INSTALL_MANDIR}/man1)
install(FILES ${mbc_bash} DESTINATION ${CMAKE_INSTALL_DATADIR}/bash-completion/completions)

# The plugin ABI and the example plugin's source (conformance/plugin/README.md).
install(FILES ${CMAKE_SOURCE_DIR}/conformance/plugin/mbconform_plugin.h DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(DIRECTORY ${CMAKE_SOURCE_DIR}/conformance/plugin/example/ DESTINATION ${MBC_SHARE}/plugin/example)

# The client adapters (`mbconform client`) and the npm lock file of the peers
# they drive, when the tree has them.
if(IS_DIRECTORY ${CMAKE_SOURCE_DIR}/conformance/peers/adapters)
  install(DIRECTORY ${CMAKE_SOURCE_DIR}/conformance/peers/adapters/ DESTINATION ${MBC_SHARE}/client/adapters)
endif()
foreach(adapter libmodbus_adapter)
  if(TARGET ${adapter})
    install(TARGETS ${adapter} RUNTIME DESTINATION ${MBC_SHARE}/client/adapters/bin)
  endif()
endforeach()
file(GLOB mbc_peer_files ${CMAKE_SOURCE_DIR}/conformance/peers/package.json ${CMAKE_SOURCE_DIR}/conformance/peers/package-lock.json)
if(mbc_peer_files)
  install(FILES ${mbc_peer_files} DESTINATION ${MBC_SHARE}/client/peers)
endif()

# What a user reads, and the licence: LICENSE (Apache-2.0) and the Debian
# copyright file (what mbconform links and builds in, under which licence).
set(MBCONFORM_HOMEPAGE "https://github.com/mbconform/mbconform" CACHE STRING "the project's home page (the .deb's Homepage)")
# The .deb's Maintainer. The default is a placeholder: the project has no
# mailing list yet; a release build names its own (-DMBCONFORM_PACKAGE_CONTACT=...).
set(MBCONFORM_PACKAGE_CONTACT "mbconform maintainers <maintainers@mbconform.invalid>"
    CACHE STRING "the .deb's Maintainer: Name <address>")
configure_file(${CMAKE_SOURCE_DIR}/cmake/debian/copyright.in ${CMAKE_BINARY_DIR}/debian/copyright @ONLY)
install(FILES ${CMAKE_BINARY_DIR}/debian/copyright ${CMAKE_SOURCE_DIR}/LICENSE DESTINATION ${CMAKE_INSTALL_DOCDIR})
install(FILES ${CMAKE_SOURCE_DIR}/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
# The README's links into docs/ hold in the installed copy too.
install(DIRECTORY ${CMAKE_SOURCE_DIR}/docs/ DESTINATION ${CMAKE_INSTALL_DOCDIR}/docs FILES_MATCHING PATTERN "*.md")
install(FILES ${CMAKE_SOURCE_DIR}/spec/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR} RENAME spec-language.md)
install(FILES ${CMAKE_SOURCE_DIR}/conformance/plugin/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR} RENAME plugin.md)

# The Debian package. Its dependencies are the Debian packages of the shared
# libraries mbconform links, found by dpkg-shlibdeps, not a hand-kept list.
set(CPACK_PACKAGE_NAME mbconform)
set(CPACK_PACKAGE_VENDOR "mbconform")
set(CPACK_PACKAGE_CONTACT "${MBCONFORM_PACKAGE_CONTACT}")
set(CPACK_RESOURCE_FILE_LICENSE ${CMAKE_SOURCE_DIR}/LICENSE)
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "Modbus conformance and fuzz test suite for industrial motor drives")
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION devel)
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_STRIP_FILES ON)  # RelWithDebInfo binaries carry their debug info otherwise
set(CPACK_DEBIAN_PACKAGE_HOMEPAGE "${MBCONFORM_HOMEPAGE}")
include(CPack)

# Tests: install into a scratch prefix and use it from outside the source
# tree; build the .deb and let apt resolve its dependencies.
add_test(NAME install_from_prefix
  COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/install_test.sh ${CMAKE_BINARY_DIR}
          ${CMAKE_SOURCE_DIR} ${PROJECT_VERSION})
set_tests_properties(install_from_prefix PROPERTIES LABELS install TIMEOUT 600)
add_test(NAME deb_package COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/deb_test.sh ${CMAKE_BINARY_DIR} ${CMAKE_CURRENT_BINARY_DIR}/deb-test
         ${CMAKE_SOURCE_DIR} ${PROJECT_VERSION})
set_tests_properties(deb_package PROPERTIES LABELS install TIMEOUT 900)
# Both install the same tree: one after the other.
set_tests_properties(install_from_prefix deb_package PROPERTIES RESOURCE_LOCK mbconform_install)

# The command line's conventions (cmake/tests/cli_test.sh), the man page and
# the completion against every command's help (manual_test.py), and the
# README's first screen (readme_test.py).
add_test(NAME cli_conventions COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/cli_test.sh $<TARGET_FILE:mbconform> ${PROJECT_VERSION}
         ${CMAKE_SOURCE_DIR} ${CMAKE_CURRENT_BINARY_DIR}/cli-test)
add_test(NAME cli_manual COMMAND /usr/bin/python3 ${CMAKE_SOURCE_DIR}/cmake/tests/manual_test.py $<TARGET_FILE:mbconform>
         ${mbc_man} ${mbc_bash})
add_test(NAME readme_first_page COMMAND /usr/bin/python3 ${CMAKE_SOURCE_DIR}/cmake/tests/readme_test.py ${CMAKE_SOURCE_DIR}
         $<TARGET_FILE:mbconform>)
set_tests_properties(cli_conventions cli_manual readme_first_page PROPERTIES LABELS cli TIMEOUT 300)

# docs/ci/mbconform-ci.sh, the script the documented GitHub workflow calls.
install(PROGRAMS ${CMAKE_SOURCE_DIR}/docs/ci/mbconform-ci.sh DESTINATION ${CMAKE_INSTALL_DOCDIR}/ci)
install(FILES ${CMAKE_SOURCE_DIR}/docs/ci/github-actions.yml ${CMAKE_SOURCE_DIR}/docs/ci/README.md
        DESTINATION ${CMAKE_INSTALL_DOCDIR}/ci)
foreach(mode pass fail client-fail quirks)
  add_test(NAME ci_script_${mode}
    COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/ci_script_test.sh ${mode} $<TARGET_FILE:mbconform> ${CMAKE_SOURCE_DIR}
            ${CMAKE_CURRENT_BINARY_DIR}/ci-script-${mode})
  set_tests_properties(ci_script_${mode} PROPERTIES TIMEOUT 300)
endforeach()
install(PROGRAMS ${CMAKE_SOURCE_DIR}/docs/ci/mbconform-server-ci.sh DESTINATION ${CMAKE_INSTALL_DOCDIR}/ci)
foreach(mode pass fail no-start)
  add_test(NAME ci_server_script_${mode}
    COMMAND ${CMAKE_SOURCE_DIR}/docs/ci/server_ci_test.sh ${mode} $<TARGET_FILE:mbconform> ${CMAKE_CURRENT_BINARY_DIR}/ci-server-${mode})
  set_tests_properties(ci_server_script_${mode} PROPERTIES TIMEOUT 300)
endforeach()
