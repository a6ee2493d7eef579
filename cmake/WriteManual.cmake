# Writes what the built mbconform says about itself into a file, for the
# install: the man page (`help --man`) and the bash completion
# (`completion bash`), so that neither can drift from the commands' own
# definitions (tools/mbconform/manual.cpp).
# usage: cmake -DMBCONFORM=EXE -DOUT=FILE -DARGS="help;--man" -P WriteManual.cmake
get_filename_component(dir ${OUT} DIRECTORY)
file(MAKE_DIRECTORY ${dir})
execute_process(COMMAND ${MBCONFORM} ${ARGS} OUTPUT_FILE ${OUT}.tmp RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "${MBCONFORM} ${ARGS}: exit ${rc}")
endif()
file(RENAME ${OUT}.tmp ${OUT})
