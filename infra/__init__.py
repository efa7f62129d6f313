"""Infrastructure every stage uses: files written atomically and read within bounds (``files``), the resource limits
(``limits``), the command-line helpers (``console``) and the Ray cluster (``cluster``). It imports the contracts
(``uavplace.schemas``) and no stage."""
