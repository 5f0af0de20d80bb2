$(eval $(call c_program,log-summary,tools/log-summary))
