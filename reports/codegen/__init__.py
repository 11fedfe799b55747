"""C code generation of runtime observers from their CasADi step, through Jinja2 templates."""
