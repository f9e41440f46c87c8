%
(feedloop example part program: the outline of a 40 x 30 mm plate with one rounded)
(corner, a dwell, a 10 mm bore traced clockwise, and a reversal on a line.)
(Program zero is the job's origin_m; units mm, feeds mm/min.)
N10 G21 G17 G90
N20 G0 X0 Y0
N30 G1 X40 F1500          ; bottom edge
N40 G1 Y20                ; right edge, a 90 degree corner
N50 G3 X30 Y30 I-10 J0    ; rounded corner, R10 counter-clockwise
N60 G1 X0                 ; top edge
N70 G1 Y0                 ; left edge, back to the start
N80 G4 P0.2               ; dwell 0.2 s
N90 G0 X15 Y15            ; rapid to the bore
N100 G2 X15 Y15 I5 J0 F900 (full circle R5, clockwise)
N110 G91 G1 X5            ; incremental: 5 mm right ...
N120 X-10                 ; ... and 10 mm back: a reversal on the line
N130 G90 G0 X0 Y0
N140 M30
%
