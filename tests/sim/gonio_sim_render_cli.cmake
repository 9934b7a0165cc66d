# gonio-sim-render as value_check.py uses it: a header, lines of stage angles, the beam blocked on
# one; then a bad line, which must be refused with its line number. Invoked by CTest with RENDER,
# CONFIG, WORK.
file(REMOVE_RECURSE ${WORK})
file(MAKE_DIRECTORY ${WORK})
file(WRITE ${WORK}/angles.csv "sample_deg,arm_deg,beam_blocked\n0,180\n0,175\n0,180,1\n")
execute_process(COMMAND ${RENDER} --config ${CONFIG} --rect 253,246,6,19
                INPUT_FILE ${WORK}/angles.csv
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "gonio-sim-render failed (${rc}): ${err}")
endif()
string(REPLACE "\n" ";" lines "${out}")
list(GET lines 0 header)
if(NOT header STREQUAL "sample_deg,arm_deg,beam_blocked,rate_e_per_s")
  message(FATAL_ERROR "unexpected header '${header}'")
endif()
set(rates)
foreach(k 1 2 3)
  list(GET lines ${k} row)
  string(REPLACE "," ";" cells "${row}")
  list(GET cells 3 rate)
  list(APPEND rates ${rate})
endforeach()
list(GET rates 0 peak)
list(GET rates 1 flank)
list(GET rates 2 blocked)
# Straight through the lobe's peak, 5 degrees off it, and stray light alone with the beam blocked.
if(NOT (peak GREATER flank AND flank GREATER blocked AND blocked GREATER 0))
  message(FATAL_ERROR "rates not peak > flank > blocked > 0: ${peak} ${flank} ${blocked}")
endif()
file(WRITE ${WORK}/bad.csv "sample_deg,arm_deg\n0,180\nnot a line\n")
execute_process(COMMAND ${RENDER} --config ${CONFIG} --rect 253,246,6,19
                INPUT_FILE ${WORK}/bad.csv
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "stdin:3: expected sample_deg,arm_deg")
  message(FATAL_ERROR "a bad line was not refused with its line (${rc}): ${err}")
endif()
execute_process(COMMAND ${RENDER} --config ${CONFIG} --rect 510,246,6,19
                INPUT_FILE ${WORK}/angles.csv
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "is not inside the 512 x 512 image")
  message(FATAL_ERROR "a rectangle off the image was not refused (${rc}): ${err}")
endif()
