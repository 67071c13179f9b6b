"""The conformance product: scene catalog, golden images, fault-injection mutants, the
check that runs them, and its reports (text, JUnit, HTML)."""
