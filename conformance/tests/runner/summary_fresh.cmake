# Runs `mbconform run` (every reference device) into WORK_DIR and fails when
# its stable summary differs from the committed reports/reference/.
file(REMOVE_RECURSE "${WORK_DIR}")
execute_process(COMMAND "${MBCONFORM}" run --quiet --out "${WORK_DIR}/run" --summary "${WORK_DIR}/summary"
                RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "mbconform run failed (${rc}): a MUST case fails against a reference device")
endif()
foreach(f summary.md summary.json)
  execute_process(COMMAND ${CMAKE_COMMAND} -E compare_files "${WORK_DIR}/summary/${f}" "${SOURCE_DIR}/reports/reference/${f}" RESULT_VARIABLE diff)
  if(NOT diff EQUAL 0)
    message(FATAL_ERROR "reports/reference/${f} is stale: the specs and devices now give another run; run tools/main-job.sh and commit")
  endif()
endforeach()
