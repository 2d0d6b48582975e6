# Included at the end of each interface package's CMakeLists.txt.
#
# The <pkg>__rosidl_generator_py targets exported by the ros-jazzy wheels name the wheel
# builder's Python include folder (/opt/python/cp311-cp311/include/python3.11), which does
# not exist here, so generating the build fails. Point every such imported target of this
# directory at this interpreter's and numpy's include folders instead. A no-op beside a
# full ROS 2 install, whose targets name folders that exist.
get_property(_imported DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(_target IN LISTS _imported)
  if(_target MATCHES "__rosidl_generator_py$")
    get_target_property(_includes ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    set(_missing FALSE)
    foreach(_dir IN LISTS _includes)
      if(NOT EXISTS "${_dir}")
        set(_missing TRUE)
      endif()
    endforeach()
    if(_missing)
      set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES
        "${Python3_INCLUDE_DIRS};${Python3_NumPy_INCLUDE_DIRS}")
    endif()
  endif()
endforeach()
