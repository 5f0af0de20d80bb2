# log-merge: several event logs -> one, in time order (chains replayed modules).
$(eval $(call c_program,log-merge,tools/log-merge))
