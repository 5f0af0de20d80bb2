$(eval $(call c_program,scan-export,tools/scan-export))
