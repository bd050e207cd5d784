KPL/MK

Meta-kernel of the synthetic LUNARMAP-SIM mission written by
lunarmap.synthetic.write_mission. It lives next to the kernels; the
relative PATH_VALUES '.' means this file's folder to lunarmap's
KernelSet.from_metakernel (for plain furnsh, run from this folder).

\begindata

   PATH_VALUES     = ( '.' )
   PATH_SYMBOLS    = ( 'KERNELS' )

   KERNELS_TO_LOAD = ( '$KERNELS/lunarmap_sim.tls'
                      '$KERNELS/lunarmap_sim.tsc'
                      '$KERNELS/lunarmap_sim.tpc'
                      '$KERNELS/lunarmap_sim.tf'
                      '$KERNELS/lunarmap_sim_nac.ti'
                      '$KERNELS/lunarmap_sim_frame.ti'
                      '$KERNELS/lunarmap_sim_planets.bsp'
                      '$KERNELS/lunarmap_sim_orbit.bsp'
                      '$KERNELS/lunarmap_sim_bus.bc' )

\begintext

