# perch2 generate -> estimate -> eval on a tiny MODE (3dof or 6dof; 6dof with the ground-truth masks) dataset
# (1 scene, 2 images, 2 objects, seed 5): the
# results CSV must be valid for `perch2 eval` and every target within 2 cm ADD-S (the scene is easy: objects
# apart, table frame given; a failure means the pipeline or the CLI's conversion of units/frames broke).
# Usage: cmake -DPERCH2=path/to/perch2 -DWORK_DIR=dir -DMODE=3dof|6dof -P cli_estimate_smoke.cmake
file(REMOVE_RECURSE ${WORK_DIR})
include(${CMAKE_CURRENT_LIST_DIR}/cli_common.cmake)
run(${PERCH2} generate --mode ${MODE} --scenes 1 --images-per-scene 2 --objects 2 --seed 5 --out ${WORK_DIR}/data)
run(${PERCH2} estimate --mode ${MODE} --dataset ${WORK_DIR}/data --out ${WORK_DIR}/results.csv --backend cpu
    --overlays ${WORK_DIR}/overlays)
message("${out}")
if(NOT EXISTS ${WORK_DIR}/overlays/000001_000000.png)
  message(FATAL_ERROR "no overlay written for image 0")
endif()
run(${PERCH2} eval --dataset ${WORK_DIR}/data --results ${WORK_DIR}/results.csv --no-vsd)
message("${out}")
# The "all" row: n, AUC ADD, AUC ADD-S, AUC ADD(-S), ADD-S < 1 cm %, ADD-S < 2 cm %, ...
if(NOT out MATCHES "\nall +([0-9]+) +[0-9.]+ +[0-9.]+ +[0-9.]+ +[0-9.]+ +([0-9.]+)")
  message(FATAL_ERROR "no 'all' row in the eval report")
endif()
if(CMAKE_MATCH_1 LESS 2 OR NOT CMAKE_MATCH_2 STREQUAL "100.0")
  message(FATAL_ERROR "expected >= 2 targets all within 2 cm ADD-S, got ${CMAKE_MATCH_1} targets, ${CMAKE_MATCH_2}%")
endif()
# An empty target list (no targets in the requested scenes) is a clear error, not an empty results file.
execute_process(COMMAND ${PERCH2} estimate --mode ${MODE} --dataset ${WORK_DIR}/data --scenes 50-60
                        --out ${WORK_DIR}/empty.csv RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "lists no targets in scenes 50-60")
  message(FATAL_ERROR "estimate with no targets: exit ${rc}, message: ${err}")
endif()
