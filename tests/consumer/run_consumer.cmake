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
file(GLOB_RECURSE installed_headers "${WORK_DIR}/prefix/include/perch2/*")
foreach(header ${installed_headers})
  file(STRINGS "${header}" leak REGEX "#[ \t]*include[ \t]*[<\"](thrust|cub|cuda|nv)/")
  if(leak)
    message(FATAL_ERROR "installed header ${header} includes CCCL: ${leak}")
  endif()
endforeach()
file(GLOB package_files "${WORK_DIR}/prefix/lib*/cmake/perch2/*.cmake")
foreach(f ${package_files})
  file(STRINGS "${f}" leak REGEX "CUDAToolkit|CUDA::|CCCL|Thrust")
  if(leak)
    message(FATAL_ERROR "installed package file ${f} needs the CUDA toolkit or CCCL: ${leak}")
  endif()
endforeach()
