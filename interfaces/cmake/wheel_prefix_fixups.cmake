# Make CMake targets exported by the ros-jazzy-* wheels usable in this venv.
#
# Some wheels were built with a Python at /opt/python/... and their exported targets list that
# interpreter's include directories; CMake's generate step rejects a non-existent include path.
# Call fleet_fix_wheel_include_dirs() after the find_package() calls: every imported target of
# the calling directory whose INTERFACE_INCLUDE_DIRECTORIES mentions /opt/python/ gets this
# interpreter's Python and NumPy include directories instead.
find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)

function(fleet_fix_wheel_include_dirs)
  get_property(_targets DIRECTORY PROPERTY IMPORTED_TARGETS)
  foreach(_t IN LISTS _targets)
    get_target_property(_inc ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(_inc AND "${_inc}" MATCHES "/opt/python/")
      set(_fixed)
      foreach(_d IN LISTS _inc)
        if(NOT "${_d}" MATCHES "/opt/python/")
          list(APPEND _fixed "${_d}")
        endif()
      endforeach()
      list(APPEND _fixed ${Python3_INCLUDE_DIRS} ${Python3_NumPy_INCLUDE_DIRS})
      list(REMOVE_DUPLICATES _fixed)
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_fixed}")
      message(STATUS "fleet: fixed include directories of ${_t}")
    endif()
  endforeach()
endfunction()
