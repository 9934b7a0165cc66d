# Runs gonio-synth then gonio-fit on its output, and checks what a user would look at: the exit
# status, the table, the choice, and the files written. Invoked by CTest with SYNTH, FIT, WORK.
file(REMOVE_RECURSE ${WORK})
file(MAKE_DIRECTORY ${WORK})
execute_process(COMMAND ${SYNTH} ${WORK}/ggx.csv --model ggx --width 0.394 --scale 0.755
                        --incidences 0,30,60,80 --seed 3
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "gonio-synth failed (${rc}): ${out}${err}")
endif()
execute_process(COMMAND ${FIT} ${WORK}/ggx.csv --model beckmann,ggx --out ${WORK}/fit
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
message("${out}")
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "gonio-fit failed (${rc}): ${err}")
endif()
foreach(expect "Fit at normal incidence" "Prediction of the other incidences" "Joint fit of all incidences"
               "model choice: ggx")
  string(FIND "${out}" "${expect}" at)
  if(at EQUAL -1)
    message(FATAL_ERROR "gonio-fit output lacks '${expect}'")
  endif()
endforeach()
# Quiet by default: the tables fit 100 columns, with --explain too; standard error, not a
# terminal here, has one line per model and part (2 models, normal incidence and joint) and
# nothing of the solves' steps, which -v prints.
function(check_width text what)
  string(REPLACE ";" "," text "${text}")  # a list's separator, not the text's
  string(REPLACE "\n" ";" lines "${text}")
  foreach(line IN LISTS lines)
    string(LENGTH "${line}" n)
    if(n GREATER 100)
      message(FATAL_ERROR "${what}: a line of ${n} columns: '${line}'")
    endif()
  endforeach()
endfunction()
check_width("${out}" "gonio-fit's table")
string(REGEX MATCHALL "gonio-fit: \\[[0-9]+ s\\] fitting [a-z0-9]+, (normal|all) incidences?" stages "${err}")
list(LENGTH stages n_stages)
if(NOT n_stages EQUAL 4 OR err MATCHES "local fit")
  message(FATAL_ERROR "gonio-fit's progress in a log: ${n_stages} stage lines (4 expected):\n${err}")
endif()
execute_process(COMMAND ${FIT} ${WORK}/ggx.csv --model beckmann,ggx --explain -v
                RESULT_VARIABLE rc OUTPUT_VARIABLE explained ERROR_VARIABLE steps)
check_width("${explained}" "gonio-fit --explain")
if(NOT rc EQUAL 0 OR NOT explained MATCHES "(floor kept|no floor)" OR NOT steps MATCHES "local fit 1 of")
  message(FATAL_ERROR "gonio-fit -v (${rc}) lacks the explanation or the steps:\n${explained}\n${steps}")
endif()
foreach(f fit_curves.csv empirical_d.csv fitted_d.csv fit_summary.json)
  if(NOT EXISTS ${WORK}/fit/${f})
    message(FATAL_ERROR "gonio-fit did not write ${f}")
  endif()
endforeach()
file(STRINGS ${WORK}/fit/fit_curves.csv lines)
list(LENGTH lines n)
if(NOT n EQUAL 717)
  message(FATAL_ERROR "fit_curves.csv has ${n} lines, expected 716 samples + header")
endif()
# The plot a user looks at: the script reads the directory and writes a PNG.
execute_process(COMMAND /usr/bin/python3 ${PLOT} ${WORK}/fit ${WORK}/fit/fit.png
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0 OR NOT EXISTS ${WORK}/fit/fit.png)
  message(FATAL_ERROR "plot_fit.py failed (${rc}): ${out}${err}")
endif()
file(SIZE ${WORK}/fit/fit.png png_size)
if(png_size LESS 20000)
  message(FATAL_ERROR "fit.png is only ${png_size} bytes")
endif()
