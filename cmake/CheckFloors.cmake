# The floors (modbus/README.md): a file includes only its own floor and the
# floors below it.
#   modbus/ < spec/ < reference/ < conformance/ < tools/ < fuzz/, bench/
# modbus/ further includes nothing but modbus/ and the C++ standard library
# (its tests may add gtest).
#
# Inside conformance/, each part includes only the parts listed for it
# (README.md, "Architecture"): the checks (check/) sit on the Link
# (session/) and the targets; the makers of checks (cases/, properties/,
# blackbox/) sit on check/; the runner orders and re-runs checks and never
# reaches back into a maker. tests/ may include any part.
#   conformance/runner/runner.cpp:9: includes "cases/case.h": runner/ may not include cases/
#
#   cmake -DSOURCE_DIR=<repo> -P cmake/CheckFloors.cmake
# Exit status 1 and one line per offending include:
#   spec/loader/x.cpp:7: includes "engine/device.h" (reference/engine/device.h): spec/ may not include reference/
cmake_minimum_required(VERSION 3.25)
if(NOT SOURCE_DIR)
  message(FATAL_ERROR "usage: cmake -DSOURCE_DIR=<repo> -P CheckFloors.cmake")
endif()

set(floors modbus spec reference conformance tools fuzz bench)
set(rank_modbus 0)
set(rank_spec 1)
set(rank_reference 2)
set(rank_conformance 3)
set(rank_tools 4)
set(rank_fuzz 5)
set(rank_bench 5)
# Where each floor's quoted includes resolve (its CMake include directories).
set(roots_modbus "${SOURCE_DIR}")
set(roots_spec "${SOURCE_DIR}/spec/loader;${SOURCE_DIR}/spec")
set(roots_reference "${SOURCE_DIR}/reference")
set(roots_conformance "${SOURCE_DIR}/conformance")
set(roots_tools "${SOURCE_DIR}/tools")
set(roots_fuzz "${SOURCE_DIR}/fuzz")
set(roots_bench "${SOURCE_DIR}/bench")

# conformance/<part>/ may include these parts (its own included).
set(conf_parts targets report plugin policy session safety check cases map blackbox properties runner client peers scan)
set(conf_may_targets targets)
set(conf_may_report report)
set(conf_may_plugin plugin)
set(conf_may_policy policy targets)
set(conf_may_session session policy safety targets report)  # report/utc_now.h: the one wall-clock stamp
set(conf_may_safety safety policy targets)
set(conf_may_check check policy session targets report)
set(conf_may_cases cases policy check safety targets report)
set(conf_may_map map policy cases check session safety targets report)  # the probe sends through the Link (session/link.h)
set(conf_may_blackbox blackbox policy check session safety targets report)
set(conf_may_properties properties policy cases check session safety targets report)  # cases/facts.h: the one classifier
set(conf_may_runner runner policy check session targets report)
set(conf_may_client client report targets)
set(conf_may_scan scan policy session targets)
set(conf_may_peers peers client)  # the broken master is built on the client's model

# The floor a file under SOURCE_DIR belongs to, or "" outside the floors.
function(floor_of path out)
  file(RELATIVE_PATH rel "${SOURCE_DIR}" "${path}")
  string(REGEX MATCH "^[^/]+" top "${rel}")
  if(top IN_LIST floors)
    set(${out} ${top} PARENT_SCOPE)
  else()
    set(${out} "" PARENT_SCOPE)
  endif()
endfunction()

set(violations "")
foreach(floor IN LISTS floors)
  file(GLOB_RECURSE sources "${SOURCE_DIR}/${floor}/*.h" "${SOURCE_DIR}/${floor}/*.hpp" "${SOURCE_DIR}/${floor}/*.c"
       "${SOURCE_DIR}/${floor}/*.cc" "${SOURCE_DIR}/${floor}/*.cpp")
  # The directory search order: the including file's own floor first, then
  # the others from the ground up.
  set(search ${roots_${floor}})
  foreach(other IN LISTS floors)
    if(NOT other STREQUAL floor)
      list(APPEND search ${roots_${other}})
    endif()
  endforeach()
  foreach(src IN LISTS sources)
    file(RELATIVE_PATH rel_src "${SOURCE_DIR}" "${src}")
    if(rel_src MATCHES "/node_modules/")
      continue()
    endif()
    get_filename_component(src_dir "${src}" DIRECTORY)
    # One list element per line: neutralise what CMake lists treat specially
    # (";" separates, an unbalanced "[" would swallow the rest of the file).
    file(READ "${src}" text)
    string(REPLACE ";" "," text "${text}")
    string(REPLACE "[" "(" text "${text}")
    string(REPLACE "]" ")" text "${text}")
    string(REPLACE "\\" "/" text "${text}")
    string(REPLACE "\n" ";" lines "${text}")
    set(n 0)
    foreach(line IN LISTS lines)
      math(EXPR n "${n} + 1")
      if(NOT line MATCHES "^[ \t]*#[ \t]*include[ \t]*([<\"])([^>\"]+)[>\"]")
        continue()
      endif()
      set(kind "${CMAKE_MATCH_1}")
      set(inc "${CMAKE_MATCH_2}")
      if(kind STREQUAL "<")
        # modbus/: the standard library only (<cstdint>, <vector>: no ".h", no "/").
        if(floor STREQUAL "modbus" AND NOT inc MATCHES "^[a-z_0-9]+$"
           AND NOT (rel_src MATCHES "^modbus/tests/" AND inc MATCHES "^gtest/"))
          list(APPEND violations "${rel_src}:${n}: includes <${inc}>: modbus/ includes only modbus/ and the C++ standard library")
        endif()
        continue()
      endif()
      set(found "")
      foreach(dir IN ITEMS "${src_dir}" ${search})
        if(EXISTS "${dir}/${inc}" AND NOT IS_DIRECTORY "${dir}/${inc}")
          set(found "${dir}/${inc}")
          break()
        endif()
      endforeach()
      if(found STREQUAL "")
        if(floor STREQUAL "modbus")
          list(APPEND violations "${rel_src}:${n}: includes \"${inc}\", not a file of modbus/")
        endif()
        continue()  # generated in the build tree
      endif()
      get_filename_component(found "${found}" REALPATH)
      floor_of("${found}" target)
      file(RELATIVE_PATH rel_found "${SOURCE_DIR}" "${found}")
      if(floor STREQUAL "modbus" AND NOT target STREQUAL "modbus")
        list(APPEND violations "${rel_src}:${n}: includes \"${inc}\" (${rel_found}): modbus/ includes only modbus/ and the C++ standard library")
      elseif(NOT target STREQUAL "" AND rank_${target} GREATER rank_${floor})
        list(APPEND violations "${rel_src}:${n}: includes \"${inc}\" (${rel_found}): ${floor}/ may not include ${target}/")
      elseif(floor STREQUAL "conformance" AND target STREQUAL "conformance")
        string(REGEX MATCH "^conformance/([^/]+)/" _ "${rel_src}")
        set(from "${CMAKE_MATCH_1}")
        string(REGEX MATCH "^conformance/([^/]+)/" _ "${rel_found}")
        set(to "${CMAKE_MATCH_1}")
        if(from IN_LIST conf_parts AND to IN_LIST conf_parts AND NOT to IN_LIST conf_may_${from})
          list(APPEND violations "${rel_src}:${n}: includes \"${inc}\" (${rel_found}): ${from}/ may not include ${to}/")
        endif()
      endif()
    endforeach()
  endforeach()
endforeach()

if(violations)
  list(LENGTH violations count)
  list(JOIN violations "\n" text)
  message("${text}")
  message(FATAL_ERROR "${count} include(s) reach a higher floor or a part they may not (modbus/README.md, README.md Architecture)")
endif()
