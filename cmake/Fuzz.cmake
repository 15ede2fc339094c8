# STIFFMD_FUZZ=ON (clang only): the libFuzzer targets fuzz_deck and fuzz_lammps_data
# (tests/fuzz/), with the whole engine instrumented for coverage, AddressSanitizer and UBSan.
# tools/fuzz.sh configures build-fuzz with clang-14 and runs each target:
#   cmake -S . -B build-fuzz -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 -DSTIFFMD_FUZZ=ON
# Inputs that found bugs are kept in tests/fuzz/regressions/ and replayed by every ctest run
# (fuzz_*_replay, built by tests/CMakeLists.txt with any compiler).
option(STIFFMD_FUZZ "Build the libFuzzer targets (needs clang)" OFF)

if(STIFFMD_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
    message(FATAL_ERROR "STIFFMD_FUZZ needs clang (libFuzzer): configure with "
                        "-DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14")
  endif()
  include(${CMAKE_CURRENT_LIST_DIR}/AllTargets.cmake)
  set(_stiffmd_fuzz_flags -fsanitize=fuzzer-no-link,address,undefined -fno-omit-frame-pointer
                          -fno-sanitize-recover=undefined)
  stiffmd_all_targets(_stiffmd_fuzz_instrumented)
  foreach(t IN LISTS _stiffmd_fuzz_instrumented)
    target_compile_options(${t} PRIVATE ${_stiffmd_fuzz_flags})
    target_link_options(${t} PRIVATE -fsanitize=address,undefined)
    # libFuzzer's convention: bounds that keep one input fast (engine/scene/scene_sources.cpp).
    target_compile_definitions(${t} PRIVATE FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION)
  endforeach()
  foreach(name fuzz_deck fuzz_lammps_data)
    add_executable(${name} ${PROJECT_SOURCE_DIR}/tests/fuzz/${name}.cpp)
    target_link_libraries(${name} PRIVATE stiffmd_engine stiffmd_warnings)
    target_compile_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined -fno-omit-frame-pointer
                                           -fno-sanitize-recover=undefined)
    target_compile_definitions(${name} PRIVATE FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION)
    target_link_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
  endforeach()
endif()
