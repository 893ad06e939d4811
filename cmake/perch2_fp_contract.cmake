# perch2_no_fp_contract(target): compile the target's C++ without contracting a * b + c into a fused
# multiply-add, so every backend rounds every product and sum as written (bitwise-equal results across
# perch2::cpu, perch2::thrust_omp and the default perch2::cuda build, whose nvcc flag is --fmad=false).
function(perch2_no_fp_contract target)
  if(CMAKE_CXX_COMPILER_ID MATCHES "GNU|Clang")
    target_compile_options(${target} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:-ffp-contract=off>)
  endif()
endfunction()
