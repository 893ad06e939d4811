# run(COMMAND...): runs it, stops the script with its output if it fails, and leaves its stdout in `out`.
# Included by the CLI smoke scripts (cli_*_smoke.cmake).
function(run)
  execute_process(COMMAND ${ARGV} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${ARGV} failed (${rc}):\n${out}\n${err}")
  endif()
  set(out "${out}" PARENT_SCOPE)
endfunction()
