"""Print the Markdown table of registered methods (paste it into README.md)."""

from renderers.methods import method_table

print(method_table())
