# ctest driver: install perch2 from BUILD_DIR into a scratch prefix, build tests/consumer against it with
# CONSUMER_CXX_FLAGS (e.g. -march=native), run it.
foreach(step
    "${CMAKE_COMMAND};--install;${BUILD_DIR};--prefix;${WORK_DIR}/prefix"
    "${CMAKE_COMMAND};-S;${SOURCE_DIR};-B;${WORK_DIR}/build;-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix;-DCMAKE_BUILD_TYPE=Release;-DCMAKE_CXX_FLAGS=${CONSUMER_CXX_FLAGS};-DCMAKE_CXX_COMPILER_LAUNCHER=${LAUNCHER}"
    "${CMAKE_COMMAND};--build;${WORK_DIR}/build"
    "${WORK_DIR}/build/consumer")
  execute_process(COMMAND ${step} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "consumer step failed (${rc}): ${step}\n${out}\n${err}")
  endif()
endforeach()
message(STATUS "consumer built with flags '${CONSUMER_CXX_FLAGS}':\n${out}")

# Thrust/CUB/libcu++ and the CUDA toolkit are private build dependencies: no installed header or package
# file may ask for them (a machine with Debian's copies in /usr/include would hide such a leak at compile time).
function(forbid glob regex what)
  file(GLOB_RECURSE files "${WORK_DIR}/prefix/${glob}")
  foreach(f ${files})
    file(STRINGS "${f}" leak REGEX "${regex}")
    if(leak)
      message(FATAL_ERROR "installed ${f} ${what}: ${leak}")
    endif()
  endforeach()
endfunction()
forbid("include/perch2/*" "#[ \t]*include[ \t]*[<\"](thrust|cub|cuda|nv)/" "includes CCCL")
forbid("lib*/cmake/perch2/*.cmake" "CUDAToolkit|CUDA::|CCCL|Thrust" "needs the CUDA toolkit or CCCL")
