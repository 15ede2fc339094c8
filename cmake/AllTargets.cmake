# stiffmd_all_targets(<out-var>): every target defined so far in this project (the top-level
# directory and, recursively, its subdirectories), without imported or alias targets. Used by
# Sanitize.cmake and Fuzz.cmake, which are included at the end of the top-level CMakeLists.txt
# and so must add their flags to targets that already exist (add_compile_options would only
# reach targets created after it).
include_guard(GLOBAL)

function(_stiffmd_targets_in dir out)
  get_property(targets DIRECTORY "${dir}" PROPERTY BUILDSYSTEM_TARGETS)
  get_property(subdirs DIRECTORY "${dir}" PROPERTY SUBDIRECTORIES)
  foreach(sub IN LISTS subdirs)
    _stiffmd_targets_in("${sub}" sub_targets)
    list(APPEND targets ${sub_targets})
  endforeach()
  set(${out} ${targets} PARENT_SCOPE)
endfunction()

function(stiffmd_all_targets out)
  _stiffmd_targets_in("${PROJECT_SOURCE_DIR}" all)
  set(result "")
  foreach(t IN LISTS all)
    get_target_property(type ${t} TYPE)
    # Only targets that compile or link code: not INTERFACE libraries or custom targets.
    if(type MATCHES "^(EXECUTABLE|STATIC_LIBRARY|SHARED_LIBRARY|MODULE_LIBRARY|OBJECT_LIBRARY)$")
      list(APPEND result ${t})
    endif()
  endforeach()
  set(${out} ${result} PARENT_SCOPE)
endfunction()
