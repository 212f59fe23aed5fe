# Installs the built cellforce into WORK_DIR/prefix, configures and builds the consumer project
# (tests/consumer) against that prefix, runs consumer_c and consumer_cpp and requires the same
# output from both. Run by ctest as package_consumer:
#   cmake -DBUILD_DIR=... -DSOURCE_DIR=tests/consumer -DWORK_DIR=... -P run_consumer.cmake
include(${CMAKE_CURRENT_LIST_DIR}/package_build.cmake)
foreach(program consumer_c consumer_cpp)
  execute_process(COMMAND ${WORK_DIR}/build/${program} RESULT_VARIABLE rc
                  OUTPUT_FILE ${WORK_DIR}/${program}.txt ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${program} failed (${rc}): ${err}")
  endif()
endforeach()
file(READ ${WORK_DIR}/consumer_c.txt c_out)
file(READ ${WORK_DIR}/consumer_cpp.txt cpp_out)
string(LENGTH "${c_out}" length)
if(length LESS 1000)
  message(FATAL_ERROR "consumer_c printed too little:\n${c_out}")
endif()
if(NOT c_out STREQUAL cpp_out)
  message(FATAL_ERROR "consumer_c and consumer_cpp printed different results (${WORK_DIR}/consumer_c.txt, consumer_cpp.txt)")
endif()
# The version macros of the installed headers are the installed library's version.
string(REGEX MATCH "cellforce ([^\n]*)\nheaders ([^\n]*)" version_lines "${c_out}")
if(NOT CMAKE_MATCH_1 STREQUAL CMAKE_MATCH_2 OR CMAKE_MATCH_1 STREQUAL "")
  message(FATAL_ERROR "the library says version '${CMAKE_MATCH_1}', the headers' macros '${CMAKE_MATCH_2}'")
endif()
string(REGEX MATCH "energy [^\n]*" energy_line "${c_out}")
message(STATUS "package consumer: C and C++ agree bit for bit; ${energy_line}")
