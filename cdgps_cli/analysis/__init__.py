"""Analysis of estimates: spectra and modal identification, rest detection."""
