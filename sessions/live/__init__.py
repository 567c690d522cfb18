"""The live session: build the plugins from config, run the loop, gate the haptic force."""
