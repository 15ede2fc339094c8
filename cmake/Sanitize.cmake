# STIFFMD_SANITIZE=ON: AddressSanitizer + UndefinedBehaviorSanitizer for every target (compile
# and link), any undefined behaviour fatal:
#   cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSTIFFMD_SANITIZE=ON
#   cmake --build build-asan -j2 && (cd build-asan && ctest -j2 --output-on-failure)
# Included at the end of the top-level CMakeLists.txt, after every target exists: the flags are
# added to each target (add_compile_options there would reach none of them).
option(STIFFMD_SANITIZE "Build every target with AddressSanitizer and UndefinedBehaviorSanitizer" OFF)

if(STIFFMD_SANITIZE)
  include(${CMAKE_CURRENT_LIST_DIR}/AllTargets.cmake)
  set(STIFFMD_SANITIZE_FLAGS -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
  stiffmd_all_targets(_stiffmd_sanitized)
  foreach(t IN LISTS _stiffmd_sanitized)
    target_compile_options(${t} PRIVATE ${STIFFMD_SANITIZE_FLAGS})
    target_link_options(${t} PRIVATE ${STIFFMD_SANITIZE_FLAGS})
  endforeach()
  message(STATUS "stiffmd: AddressSanitizer + UBSan on ${_stiffmd_sanitized}")
endif()
