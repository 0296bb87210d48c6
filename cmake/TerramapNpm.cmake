# terramap_npm_ci(TARGET PACKAGE_DIR OUT_DIR COMMENT): installs PACKAGE_DIR's npm packages with
# `npm ci` from its committed package.json and package-lock.json into OUT_DIR/node_modules at build
# time (nothing is fetched at run time), and adds TARGET (built by default) for it. Used by the live
# view's page (web/) and the ROS 2 interoperability tests (tests/ros2/). Needs TERRAMAP_NPM.
function(terramap_npm_ci target package_dir out_dir comment)
  set(_stamp ${out_dir}/node_modules/.package-lock.json)
  add_custom_command(OUTPUT ${_stamp}
    COMMAND ${CMAKE_COMMAND} -E make_directory ${out_dir}
    COMMAND ${CMAKE_COMMAND} -E copy ${package_dir}/package.json ${package_dir}/package-lock.json ${out_dir}
    COMMAND ${TERRAMAP_NPM} ci --no-audit --no-fund --loglevel=error
    WORKING_DIRECTORY ${out_dir}
    DEPENDS ${package_dir}/package.json ${package_dir}/package-lock.json
    COMMENT "${comment}")
  add_custom_target(${target} ALL DEPENDS ${_stamp})
endfunction()
