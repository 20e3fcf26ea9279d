# modalfem: `make demo` and `make test` set everything up on first use (idempotent).
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= out/demo

.PHONY: setup demo test test-fast bench clean

setup:
	@bash scripts/setup.sh $(VENV)

demo: setup
	@$(PY) -m modalfem modes box --size 1.0 0.1 0.1 --cells 40 4 4 --material steel --fixed x0 \
	    -k 8 --degree 2 --out $(OUT)
	@echo "demo outputs in $(OUT)/: modes.json (frequencies, labels, certificate), modes.png (mode sheet), modes.xdmf/vtu (ParaView)"
	@$(PY) -m modalfem run bell-drop --out $(OUT)-bell-drop
	@echo "bell-drop scene in $(OUT)-bell-drop/: video preview.gif, sound sound/*.wav, ParaView scene.pvd, summary.json"

test: setup
	@$(PY) -m pytest tests -q

bench: setup
	@for b in modes codepath accuracy runtime tet threads ccd cloth surface view world scene record; do $(PY) -m modalfem bench $$b --out BENCHMARKS.md || exit 1; done

clean:
	rm -rf $(VENV) out .pytest_cache
