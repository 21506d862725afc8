"""The command line (jaxrb ...), its runner and the demo."""
