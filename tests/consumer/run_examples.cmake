# Installs the built cellforce into WORK_DIR/prefix, builds examples/ against it as a user's project
# and runs the examples. Each checks its own numbers and exits non-zero when a check fails (the
# lattice's energy against a lattice sum, zero forces on the lattice, the start temperature, energy
# and momentum conservation); here c_forces_md (C API) and cpp_forces_md (C++ API) must also print
# the same text, thermo row for row. cuda_own_integrator, where a CUDA compiler built it, must
# succeed too: on a GPU it checks its own energy conservation, elsewhere it prints a "skipped" line.
# ghost_particles checks that two slabs computed with their ghosts sum to the whole periodic box.
# Run by ctest as package_examples:
#   cmake -DBUILD_DIR=... -DSOURCE_DIR=examples -DWORK_DIR=... -P run_examples.cmake
include(${CMAKE_CURRENT_LIST_DIR}/package_build.cmake)

# Runs an example; its stdout in <program>_out and WORK_DIR/<program>.txt.
function(run_example program)
  execute_process(COMMAND ${WORK_DIR}/build/${program} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  file(WRITE ${WORK_DIR}/${program}.txt "${out}")
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${program} failed (${rc}):\n${out}\n${err}")
  endif()
  set(${program}_out "${out}" PARENT_SCOPE)
endfunction()

run_example(c_forces_md)
run_example(cpp_forces_md)
if(NOT c_forces_md_out STREQUAL cpp_forces_md_out)
  message(FATAL_ERROR "c_forces_md and cpp_forces_md printed different results "
                      "(${WORK_DIR}/c_forces_md.txt, cpp_forces_md.txt)")
endif()
# The thermo rows of steps 0, 50, ..., 500 and the lines of the checks the program passed.
string(REGEX MATCHALL "\n +[0-9]+ +[0-9]+\\.[0-9]+ " rows "${c_forces_md_out}")
list(LENGTH rows row_count)
foreach(line "\n +500 " "lattice energy/particle " "energy conserved: " "momentum conserved: ")
  if(NOT c_forces_md_out MATCHES "${line}" OR NOT row_count EQUAL 11)
    message(FATAL_ERROR "c_forces_md printed ${row_count} thermo rows (11 expected) or no '${line}':\n${c_forces_md_out}")
  endif()
endforeach()
string(REGEX MATCH "energy conserved: [^\n]*" conserved "${c_forces_md_out}")
message(STATUS "examples: C and C++ agree line for line; ${conserved}")

# ghost_particles: two slabs with their ghosts (cf_compute_local) sum to the whole box's call.
run_example(ghost_particles)
if(NOT ghost_particles_out MATCHES "check: [^\n]*")
  message(FATAL_ERROR "ghost_particles printed no check line:\n${ghost_particles_out}")
endif()
message(STATUS "examples: ghost_particles: ${CMAKE_MATCH_0}")

if(EXISTS ${WORK_DIR}/build/cuda_own_integrator)
  run_example(cuda_own_integrator)
  if(NOT cuda_own_integrator_out MATCHES "(skipped: [^\n]*|energy conserved: [^\n]*)")
    message(FATAL_ERROR "cuda_own_integrator printed neither a skip nor its energy check:\n${cuda_own_integrator_out}")
  endif()
  message(STATUS "examples: cuda_own_integrator: ${CMAKE_MATCH_1}")
else()
  message(STATUS "examples: cuda_own_integrator not built (no CUDA compiler)")
endif()
