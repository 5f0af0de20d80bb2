# webui: the browser bridge (Python: bridge.py) and its pages, bundled at build time with
# esbuild from the npm packages pinned in web/package-lock.json (no CDN at run time).
WEBUI_WEB  := modules/webui/web
WEBUI_OUT  := $(BUILD)/webui
WEBUI_NPM  := $(BUILD)/webui-npm
WEBUI_JS   := $(patsubst $(WEBUI_WEB)/src/%.js,$(WEBUI_OUT)/%.js,$(filter-out %/bus.js %/topdown.js %/scene.js,$(wildcard $(WEBUI_WEB)/src/*.js)))
WEBUI_HTML := $(patsubst $(WEBUI_WEB)/src/%.html,$(WEBUI_OUT)/%.html,$(wildcard $(WEBUI_WEB)/src/*.html))

PROGRAMS += $(BIN)/webui $(WEBUI_JS) $(WEBUI_HTML)

# npm ci into build/ (node_modules never in the source tree), again when the lock changes.
$(WEBUI_NPM)/.stamp: $(WEBUI_WEB)/package.json $(WEBUI_WEB)/package-lock.json | $(DEPS)
	@mkdir -p $(WEBUI_NPM)
	@cp $^ $(WEBUI_NPM)/
	@echo "  NPM     $(WEBUI_NPM)"
	@cd $(WEBUI_NPM) && npm ci --no-audit --no-fund --loglevel=error >/dev/null
	@touch $@

$(WEBUI_OUT)/%.js: $(WEBUI_WEB)/src/%.js $(wildcard $(WEBUI_WEB)/src/*.js) $(WEBUI_NPM)/.stamp
	@mkdir -p $(@D)
	@echo "  ESBUILD $(notdir $@)"
	@NODE_PATH=$(WEBUI_NPM)/node_modules $(WEBUI_NPM)/node_modules/.bin/esbuild $< --bundle --minify --format=iife \
	    --target=es2020 --log-level=warning --outfile=$@

$(WEBUI_OUT)/%.html: $(WEBUI_WEB)/src/%.html
	@mkdir -p $(@D)
	@cp $< $@

$(BIN)/webui: modules/webui/bridge.py modules/webui/module.mk
	@mkdir -p $(@D)
	@echo "  GEN     webui"
	@printf '#!/bin/sh\n# the webui bridge (modules/webui/bridge.py) with the project venv\nexec "%s" "%s" "$$@"\n' \
	    "$(VPY)" "$(TOP)/modules/webui/bridge.py" > $@ && chmod +x $@

# Latency bus -> browser and Proceed -> bus, memory with a slow client (10 min); baseline:
# foxglove-sdk's WebSocket server on the same feed. Table + build/bench/webui.json.
.PHONY: bench-webui
BENCH_TARGETS += bench-webui
bench-webui: all
	@$(VPY) modules/webui/bench/bench_webui.py $(BENCH_WEBUI_ARGS)
