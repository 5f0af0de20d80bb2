# study-report (Python, in .venv): recordings and questionnaires to the twinned-study report.
# study-synth: synthetic twinned sessions from a participant model (lab twin + simdrive + director).
PROGRAMS += $(BIN)/study-report $(BIN)/study-synth
$(BIN)/study-report: tools/study-report/study_report.py | $(DEPS)
	@mkdir -p $(@D)
	@printf '#!/bin/sh\nexec "%s" "%s" "$$@"\n' "$(VPY)" "$(TOP)/tools/study-report/study_report.py" > $@
	@chmod +x $@
$(BIN)/study-synth: tools/study-report/study_synth.py | $(DEPS)
	@mkdir -p $(@D)
	@printf '#!/bin/sh\nexec "%s" "%s" "$$@"\n' "$(VPY)" "$(TOP)/tools/study-report/study_synth.py" > $@
	@chmod +x $@

# check-study: the full synthetic study (32 participants, both orders, both platforms, the
# site's five scenarios) made, reported and checked: every coded decision against the
# participant model's, every director-reported collision counted once. Writes
# build/bench/study.json. make test runs the same checks on 3 participants.
.PHONY: check-study
check-study: $(BIN)/study-report $(BIN)/study-synth $(BIN)/lab_vehicle $(BIN)/director $(BIN)/simdrive $(BIN)/log-merge
	@$(VPY) tools/study-report/check_study.py --participants 32 --work $(BUILD)/check-study --json $(BUILD)/bench/study.json
