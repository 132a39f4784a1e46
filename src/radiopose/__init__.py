"""radiopose: passive position *and* orientation estimation from RSS.

A wireless device radiates unevenly. Given the device's enrolled radiation
pattern, a site survey and the RSS a few fixed receivers measure of each of
its packets, radiopose scores every candidate position x orientation, clusters
the best matches and keeps only the clusters a human-held device could reach
from its last estimate.

The modules follow the pipeline, lower layers never importing higher ones::

    units, errors, tables   conversions, one-line input errors, CSV tables
    geometry                frames, poses, direction -> pattern angles
    patterns                pattern value object, enrolment, importers, synthesis
    site                    receivers, devices, survey correction + interpolation
    capture                 pcap/radiotap ingest, packet synchronisation
    likelihood              candidate scoring (reference + fast kernels), top-k
    clustering, motion      DBSCAN with wrap, rotation and movement models
    tracker, baselines      streaming tracker and methods, log-distance LMS
    simulate                scenarios, trajectories, writers
    evaluate, security      sweeps, figures, spoofing analysis
    server, receiver        live system
    cli                     command line (parsing and printing only)

Axis and file conventions: ``docs/conventions.md`` (mirrors the interchange
contract ``formats.md``).
"""

__version__ = "0.1.0"
