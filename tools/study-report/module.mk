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
