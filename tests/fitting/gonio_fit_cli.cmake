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
