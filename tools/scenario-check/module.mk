# scenario-check: scenario files against their site (the director's loader plus route/car checks).
$(eval $(call c_program,scenario-check,tools/scenario-check modules/director/core,-lccd))
