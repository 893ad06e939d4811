# Chooses the Thrust / CUB / libcu++ headers (CCCL) that perch2::thrust_omp is compiled against with g++.
#   - the CUDA toolkit's CCCL (its include/cccl folder) when find_package(CUDAToolkit) finds one;
#   - else the system's copies in the default include path, e.g. Debian's libthrust-dev, libcub-dev and
#     libcu++-dev (1.17.2 / 1.17.2 / 1.8.1 on Debian 12), so a CPU-only user needs no toolkit;
#   - PERCH2_FORCE_SYSTEM_CCCL=ON takes the system copies even when the toolkit exists (CI builds the CPU
#     backends this way once so the fallback cannot rot).
# CCCL is a private build dependency: no public header includes it and the installed package does not look
# for it. Sets PERCH2_CCCL_INCLUDE_DIRS (private include folders of perch2::thrust_omp; empty when the
# headers sit in the compiler's default path) and PERCH2_CCCL_DESCRIPTION. The toolkit itself (cudart) is
# still found when present: perch2::cuda needs it.
option(PERCH2_FORCE_SYSTEM_CCCL
       "Compile perch2::thrust_omp against the system's Thrust/CUB/libcu++ even when the CUDA toolkit is found"
       OFF)

find_package(CUDAToolkit QUIET)

# Reads "#define NAME value" from a header; empty if absent.
function(perch2_header_define header name out)
  set(value "")
  if(EXISTS "${header}")
    file(STRINGS "${header}" line REGEX "^#[ \t]*define[ \t]+${name}[ \t]+[0-9]+")
    string(REGEX REPLACE ".*${name}[ \t]+([0-9]+).*" "\\1" value "${line}")
  endif()
  set(${out} "${value}" PARENT_SCOPE)
endfunction()

# "major.minor.patch" of the Thrust found in dir (THRUST_VERSION = major * 100000 + minor * 100 + patch).
function(perch2_thrust_version dir out)
  perch2_header_define("${dir}/thrust/version.h" THRUST_VERSION v)
  if(v)
    math(EXPR major "${v} / 100000")
    math(EXPR minor "(${v} / 100) % 1000")
    math(EXPR patch "${v} % 100")
    set(${out} "${major}.${minor}.${patch}" PARENT_SCOPE)
  else()
    set(${out} "unknown" PARENT_SCOPE)
  endif()
endfunction()

if(CUDAToolkit_FOUND AND NOT PERCH2_FORCE_SYSTEM_CCCL)
  find_path(PERCH2_TOOLKIT_CCCL_DIR thrust/version.h
            HINTS ${CUDAToolkit_INCLUDE_DIRS}/cccl ${CUDAToolkit_INCLUDE_DIRS} NO_DEFAULT_PATH)
  if(NOT PERCH2_TOOLKIT_CCCL_DIR)
    message(FATAL_ERROR "perch2: the CUDA toolkit in ${CUDAToolkit_INCLUDE_DIRS} has no Thrust headers "
                        "(thrust/version.h); configure with -DPERCH2_FORCE_SYSTEM_CCCL=ON to use the system's")
  endif()
  # The toolkit's include folder comes too: its CCCL may include toolkit headers beside it.
  set(PERCH2_CCCL_INCLUDE_DIRS ${PERCH2_TOOLKIT_CCCL_DIR} ${CUDAToolkit_INCLUDE_DIRS})
  perch2_thrust_version("${PERCH2_TOOLKIT_CCCL_DIR}" _perch2_thrust)
  set(PERCH2_CCCL_DESCRIPTION
      "the CUDA toolkit ${CUDAToolkit_VERSION}'s CCCL in ${PERCH2_TOOLKIT_CCCL_DIR} (Thrust ${_perch2_thrust})")
else()
  # Only the compiler's default path and CMake's prefixes: never the toolkit's folders.
  find_path(PERCH2_SYSTEM_THRUST_DIR thrust/version.h)
  find_path(PERCH2_SYSTEM_CUB_DIR cub/version.cuh)
  find_path(PERCH2_SYSTEM_LIBCUDACXX_DIR cuda/atomic)
  foreach(dir PERCH2_SYSTEM_THRUST_DIR PERCH2_SYSTEM_CUB_DIR PERCH2_SYSTEM_LIBCUDACXX_DIR)
    if(NOT ${dir})
      if(PERCH2_FORCE_SYSTEM_CCCL)
        set(_perch2_why "PERCH2_FORCE_SYSTEM_CCCL is ON")
      else()
        set(_perch2_why "no CUDA toolkit was found")
      endif()
      message(FATAL_ERROR
              "perch2: ${_perch2_why} and the system has no Thrust/CUB/libcu++ headers (${dir} not found). "
              "Install them (Debian/Ubuntu: apt-get install libthrust-dev libcub-dev libcu++-dev) or the "
              "CUDA toolkit.")
    endif()
  endforeach()
  set(PERCH2_CCCL_INCLUDE_DIRS ${PERCH2_SYSTEM_THRUST_DIR} ${PERCH2_SYSTEM_CUB_DIR}
                               ${PERCH2_SYSTEM_LIBCUDACXX_DIR})
  list(REMOVE_DUPLICATES PERCH2_CCCL_INCLUDE_DIRS)
  perch2_thrust_version("${PERCH2_SYSTEM_THRUST_DIR}" _perch2_thrust)
  set(PERCH2_CCCL_DESCRIPTION "the system's Thrust ${_perch2_thrust} / CUB / libcu++ in ${PERCH2_CCCL_INCLUDE_DIRS}")
  if(PERCH2_FORCE_SYSTEM_CCCL)
    string(APPEND PERCH2_CCCL_DESCRIPTION " (PERCH2_FORCE_SYSTEM_CCCL=ON)")
  endif()
endif()
message(STATUS "perch2: perch2::thrust_omp is compiled against ${PERCH2_CCCL_DESCRIPTION}")
