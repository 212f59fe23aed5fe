# The shared library's ABI as its policy states it (README, "The library"; docs/development.md):
#  - its SONAME is libcellforce.so.<MAJOR>, the project's major version;
#  - it exports the C API (cf_*) and the C++ API in the inline namespace cellforce::v<MAJOR>, and
#    nothing else (a program built against another major version's headers names other symbols);
#  - no exported name takes or returns a type of libstdc++'s new string ABI (std::__cxx11::...,
#    [abi:cxx11]), so that programs built with -D_GLIBCXX_USE_CXX11_ABI=0 link.
# Run by ctest as library_abi:
#   cmake -DLIBRARY=libcellforce.so -DMAJOR=0 -DNM=nm -DREADELF=readelf -P library_abi.cmake
foreach(var LIBRARY MAJOR NM READELF)
  if(NOT DEFINED ${var} OR "${${var}}" STREQUAL "")
    message(FATAL_ERROR "${CMAKE_SCRIPT_MODE_FILE}: -D${var}=... is required")
  endif()
endforeach()

execute_process(COMMAND ${READELF} -d ${LIBRARY} RESULT_VARIABLE rc OUTPUT_VARIABLE dynamic ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "${READELF} -d ${LIBRARY} failed (${rc}): ${err}")
endif()
string(REGEX MATCH "Library soname: \\[([^]]*)\\]" unused "${dynamic}")
if(NOT CMAKE_MATCH_1 STREQUAL "libcellforce.so.${MAJOR}")
  message(FATAL_ERROR "SONAME '${CMAKE_MATCH_1}', expected 'libcellforce.so.${MAJOR}' (the major version)")
endif()

execute_process(COMMAND ${NM} -D -C --defined-only ${LIBRARY} RESULT_VARIABLE rc OUTPUT_VARIABLE symbols
                ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "${NM} -D -C --defined-only ${LIBRARY} failed (${rc}): ${err}")
endif()
string(REPLACE ";" "\\;" symbols "${symbols}")
string(REPLACE "\n" ";" lines "${symbols}")
set(api "cellforce::v${MAJOR}::")
set(c_count 0)
set(cpp_count 0)
set(wrong "")
foreach(line IN LISTS lines)
  # "ADDRESS TYPE NAME" (the name demangled, spaces and all)
  if(NOT line MATCHES "^[0-9a-fA-F]+ [A-Za-z] (.*)$")
    continue()
  endif()
  set(name "${CMAKE_MATCH_1}")
  if(name MATCHES "__cxx11|abi:cxx11")
    string(APPEND wrong "\n  of the new string ABI: ${name}")
  elseif(name MATCHES "^cf_[a-z_]+$")
    math(EXPR c_count "${c_count} + 1")
  elseif(name MATCHES "^(typeinfo for |typeinfo name for |vtable for )?cellforce::v${MAJOR}::")
    math(EXPR cpp_count "${cpp_count} + 1")
  else()
    string(APPEND wrong "\n  neither cf_* nor ${api}: ${name}")
  endif()
endforeach()
if(NOT wrong STREQUAL "")
  message(FATAL_ERROR "${LIBRARY} exports names outside its ABI:${wrong}")
endif()
# The check above holds vacuously for a library that exports nothing: the API must be there.
foreach(needed "cf_create" "cf_compute" "${api}Context::Context(int)" "${api}version()"
               "typeinfo for ${api}Error")
  string(FIND "${symbols}" "${needed}" at)
  if(at EQUAL -1)
    message(FATAL_ERROR "${LIBRARY} does not export ${needed}")
  endif()
endforeach()
message(STATUS "library ABI: SONAME libcellforce.so.${MAJOR}; ${c_count} C functions and ${cpp_count} C++ names "
               "in ${api}, none of the new string ABI")
