"""The experiment harness: table cells, their cache, reports and figures."""
