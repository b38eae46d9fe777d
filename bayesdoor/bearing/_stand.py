"""What the CWRU stand's drive-end records are: their sampling rate and resonance band."""

#: the sampling rate of the CWRU drive-end records modelled, Hz
FS = 12000.0

#: the resonance region of the CWRU drive-end records, Hz: the band whose envelope the
#: classifier and the envelope rule read (the real fault records put their energy at
#: 2.5-3.75 kHz and about 5 kHz; the anti-alias filter cuts above 5.4 kHz)
BAND_HZ = (2000.0, 4500.0)
