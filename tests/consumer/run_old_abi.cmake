# Installs the built cellforce into WORK_DIR/prefix, builds tests/old_abi_consumer against it with
# -D_GLIBCXX_USE_CXX11_ABI=0 (a failing link fails here, naming the symbols) and runs it: it checks
# its own numbers, and its output must hold the lines of every call it makes across the ABI. Run by
# ctest as package_old_abi:
#   cmake -DBUILD_DIR=... -DSOURCE_DIR=tests/old_abi_consumer -DWORK_DIR=... -P run_old_abi.cmake
include(${CMAKE_CURRENT_LIST_DIR}/package_build.cmake)
execute_process(COMMAND ${WORK_DIR}/build/old_abi RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
file(WRITE ${WORK_DIR}/old_abi.txt "${out}")
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "old_abi failed (${rc}):\n${out}\n${err}")
endif()
foreach(line "energy -?[0-9.e+-]+ \\(analytic " "force 2 " "error: [^\n]*cutoff" "backend: cpu\n"
             "neighbor: none, stages 1-3 every evaluation \\(auto: no skin on the cpu\\)\n"
             "run: 10 steps, " "statistics_json: {[^\n]*\"run\":{")
  if(NOT out MATCHES "${line}")
    message(FATAL_ERROR "old_abi printed no line matching '${line}':\n${out}")
  endif()
endforeach()
message(STATUS "package old ABI: built with -D_GLIBCXX_USE_CXX11_ABI=0, linked and ran:\n${out}")
