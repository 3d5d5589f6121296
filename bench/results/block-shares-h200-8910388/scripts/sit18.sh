#!/bin/bash
# A/B: old = HEAD before the block-share kernels lost their integer divisions, new = this tree. Per-kernel device
# times of Warp CUDA frames (prof_frame.py), then bench_render frames + stages, alternated.
export PYTHONUNBUFFERED=1
nvidia-smi -L > $OUT/gpu.txt
for t in old new; do
  rm -rf /opt/dev/$t && mkdir -p /opt/dev/$t
  if [ $t = old ]; then SRC=.whl/ab/old; else SRC=.; fi
  cp -r $SRC/warp_biscale /opt/dev/$t/ && cp -r $SRC/kernels /opt/dev/$t/warp_biscale/kernels && cp -r $SRC/cl /opt/dev/$t/warp_biscale/cl
done
[ -n "$PROF" ] && for t in old new; do PYTHONPATH=/opt/dev/site:/opt/dev/$t timeout 200 python3 -P .whl/prof_frame.py $PWD > $OUT/prof_$t.txt 2>&1; echo "prof $t"; grep -v Warn $OUT/prof_$t.txt | grep "ms"; done
SWEEP="--lobes 8 --lights 1 --terms 16 --shadow-samples 16 --occlusion-samples 16"
for r in $ROUNDS; do for t in old new; do
PYTHONPATH=/opt/dev/site:/opt/dev/$t timeout 150 python3 -P bench/bench_render.py --parts frames stages --sizes 1920x1080 $SWEEP --backends opencl:nvidia warp:cuda --runs 5 --block-rays 4 --out $OUT/x$t$r > $OUT/$t$r.log 2>&1; echo "$t$r rc $?"
grep "size \|trace_shadows (16 rays, 4x4\|trace_occlusion (16 rays, 4x4\|shade (4x4" $OUT/$t$r.log | sed 's/ J=8.*blocks=/ blocks=/'
done; done
rm -rf $OUT/xold* $OUT/xnew*
