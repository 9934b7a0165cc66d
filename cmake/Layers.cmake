# Layering enforced by the build (cmake/layers.txt says who may include whom).
#
# Every source includes our headers by their path from the repository root ("devices/camera.h").
# Instead of exporting the whole root, gonio_layer() gives a target an include root of its own,
# a folder of symbolic links to just the folders its layer may see; beside it, a folder of
# stand-in headers, one for each header of every other folder, that stops the build with an
# #error naming the rule. A forbidden include therefore fails to compile with a message, and
# scripts/check-layers.sh says the same for every file before anything is built.

set(GONIO_LAYER_FOLDERS "")
file(STRINGS ${PROJECT_SOURCE_DIR}/cmake/layers.txt _gonio_layer_lines REGEX "^[a-z]+:")
foreach(line IN LISTS _gonio_layer_lines)
  string(REGEX MATCH "^([a-z]+):(.*)$" _ ${line})
  set(folder ${CMAKE_MATCH_1})
  string(STRIP "${CMAKE_MATCH_2}" deps)
  separate_arguments(deps)
  list(APPEND GONIO_LAYER_FOLDERS ${folder})
  set(GONIO_LAYER_DEPS_${folder} ${deps})
endforeach()
set(_gonio_all_folders ${GONIO_LAYER_FOLDERS} tests bench)

# The two include folders of one layer, made once per configure.
function(_gonio_make_layer folder)
  set(root ${PROJECT_BINARY_DIR}/layers/${folder})
  get_property(done GLOBAL PROPERTY GONIO_LAYER_MADE_${folder})
  if(done)
    return()
  endif()
  set_property(GLOBAL PROPERTY GONIO_LAYER_MADE_${folder} TRUE)
  file(REMOVE_RECURSE ${root})
  file(MAKE_DIRECTORY ${root}/allowed ${root}/refused)
  set(allowed ${folder} ${GONIO_LAYER_DEPS_${folder}})
  foreach(a IN LISTS allowed)
    file(CREATE_LINK ${PROJECT_SOURCE_DIR}/${a} ${root}/allowed/${a} SYMBOLIC)
  endforeach()
  foreach(other IN LISTS _gonio_all_folders)
    if(other IN_LIST allowed)
      continue()
    endif()
    file(GLOB_RECURSE headers RELATIVE ${PROJECT_SOURCE_DIR} CONFIGURE_DEPENDS
         ${PROJECT_SOURCE_DIR}/${other}/*.h)
    foreach(h IN LISTS headers)
      file(WRITE ${root}/refused/${h}
        "#error \"layering: ${folder}/ may not include ${h} - see cmake/layers.txt\"\n")
    endforeach()
  endforeach()
endfunction()

# gonio_layer(<target> <folder>): <target>'s sources see only <folder>'s layer. The allowed root
# is passed on to whoever links the target (its public headers include from it); the refusing
# stand-ins apply to the target's own sources only.
function(gonio_layer target folder)
  if(NOT DEFINED GONIO_LAYER_DEPS_${folder} AND NOT folder IN_LIST GONIO_LAYER_FOLDERS)
    message(FATAL_ERROR "gonio_layer: ${folder} is not in cmake/layers.txt")
  endif()
  _gonio_make_layer(${folder})
  set(root ${PROJECT_BINARY_DIR}/layers/${folder})
  get_target_property(type ${target} TYPE)
  if(type STREQUAL "INTERFACE_LIBRARY")
    target_include_directories(${target} INTERFACE ${root}/allowed)
  else()
    target_include_directories(${target} PUBLIC ${root}/allowed)
    target_include_directories(${target} PRIVATE ${root}/refused)
  endif()
endfunction()
