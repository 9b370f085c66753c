(ncmeasure friction measurement: main program FRICTION)
(machine: HMX-400)
(generated 2026-01-15 08:30 UTC by ncmeasure 0.1.0, config ccdb01d1c345377d)
(machine coordinates: #SUPPRESS OFFSETS in every move, radius compensation and tool offset off)
G17 G71 G90 G94
G40 D0
#MSG SYN ["ncmeasure: table clear, no tool, feed override 100? Cycle start to measure"]
M00
(park every axis, one at a time)
G00
#SUPPRESS OFFSETS Z-5.000
#SUPPRESS OFFSETS X375.000
#SUPPRESS OFFSETS Y300.000
(axis X: 24 windows)
L FRICTION_X.nc
(axis Y: 24 windows)
L FRICTION_Y.nc
(axis Z: 24 windows)
L FRICTION_Z.nc
M30
