$(eval $(call c_program,pose-to-tum,tools/pose-to-tum))
