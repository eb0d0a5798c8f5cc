"""Camera spectral sensitivities from one chart image under unknown light (issue 5)."""
