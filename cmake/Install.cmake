# Install rules and the Debian package (cpack -G DEB). Included last by the
# top-level CMakeLists.txt, so that optional targets (the plugin host, the
# client adapters) are known here.
#
#   cmake --install build --prefix P      P/bin/mbconform, P/share/mbconform/{devices,schema}, ...
#   (cd build && cpack -G DEB)            build/mbconform_<version>_<arch>.deb
#
# An installed mbconform finds its specs in <bin>/../share/mbconform
# (spec/loader/spec_path.h), so the tree below may be moved as a whole.
include(GNUInstallDirs)
set(MBC_SHARE ${CMAKE_INSTALL_DATADIR}/mbconform)

install(TARGETS mbconform RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
# The plugin host runs beside mbconform (conformance/targets/plugin_target.cpp).
if(TARGET mbconform-plugin-host)
  install(TARGETS mbconform-plugin-host RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
endif()

# The device specs and the language's schema.
install(DIRECTORY ${CMAKE_SOURCE_DIR}/spec/devices/ DESTINATION ${MBC_SHARE}/devices FILES_MATCHING PATTERN "*.yaml")
install(FILES ${CMAKE_SOURCE_DIR}/spec/schema/device.schema.json DESTINATION ${MBC_SHARE}/schema)

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

# What a user reads.
install(FILES ${CMAKE_SOURCE_DIR}/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
install(FILES ${CMAKE_SOURCE_DIR}/spec/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR} RENAME spec-language.md)
install(FILES ${CMAKE_SOURCE_DIR}/conformance/plugin/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR} RENAME plugin.md)

# The Debian package. Its dependencies are the Debian packages of the shared
# libraries mbconform links, found by dpkg-shlibdeps, not a hand-kept list.
set(CPACK_PACKAGE_NAME mbconform)
set(CPACK_PACKAGE_VENDOR "mbconform")
set(CPACK_PACKAGE_CONTACT "mbconform maintainers <mbconform@localhost>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "Modbus conformance and fuzz test suite for industrial motor drives")
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION devel)
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_STRIP_FILES ON)  # RelWithDebInfo binaries carry their debug info otherwise
set(CPACK_DEBIAN_PACKAGE_HOMEPAGE "https://github.com/mbconform/mbconform")
include(CPack)

# Tests: install into a scratch prefix and use it from outside the source
# tree; build the .deb and let apt resolve its dependencies.
add_test(NAME install_from_prefix
  COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/install_test.sh ${CMAKE_BINARY_DIR}
          ${CMAKE_SOURCE_DIR})
set_tests_properties(install_from_prefix PROPERTIES LABELS install TIMEOUT 300)
add_test(NAME deb_package COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/deb_test.sh ${CMAKE_BINARY_DIR} ${CMAKE_CURRENT_BINARY_DIR}/deb-test)
set_tests_properties(deb_package PROPERTIES LABELS install TIMEOUT 600)

# docs/ci/mbconform-ci.sh, the script the documented GitHub workflow calls.
install(PROGRAMS ${CMAKE_SOURCE_DIR}/docs/ci/mbconform-ci.sh DESTINATION ${CMAKE_INSTALL_DOCDIR}/ci)
install(FILES ${CMAKE_SOURCE_DIR}/docs/ci/github-actions.yml ${CMAKE_SOURCE_DIR}/docs/ci/README.md
        DESTINATION ${CMAKE_INSTALL_DOCDIR}/ci)
foreach(mode pass fail)
  add_test(NAME ci_script_${mode}
    COMMAND ${CMAKE_SOURCE_DIR}/cmake/tests/ci_script_test.sh ${mode} $<TARGET_FILE:mbconform> ${CMAKE_SOURCE_DIR}
            ${CMAKE_CURRENT_BINARY_DIR}/ci-script-${mode})
  set_tests_properties(ci_script_${mode} PROPERTIES TIMEOUT 300)
endforeach()
