"""Render targets, graphics and compute pipelines, descriptor sets.

Why these shapes: every pass in the library draws into a colour (+ optional depth) target in
GENERAL layout, uses push constants for its knobs, and viewport/scissor are dynamic so one
pipeline serves any tile. Every nested struct, list and string handed to a create call is bound
to a local variable first (the binding does not keep them alive, docs/vulkan.md: binding traps).
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Iterator, Sequence

from mgpusim.real.vulkan.buffers import COLOR_FORMAT, DEPTH_FORMAT, Buffer, Image
from mgpusim.real.vulkan.shader_cache import spirv
from mgpusim.real.vulkan.vk_errors import call, vk

if TYPE_CHECKING:
    from mgpusim.real.vulkan.device import Gpu


def shader_module(gpu: "Gpu", name: str) -> Any:
    v = vk()
    code = spirv(name)
    info = v.VkShaderModuleCreateInfo(codeSize=len(code), pCode=code)
    return call("vkCreateShaderModule", v.vkCreateShaderModule, gpu.device, info, None)


class RenderTarget:
    """Colour RGBA8 (+ D16 depth) images, a render pass that clears or loads them, a framebuffer."""

    def __init__(self, gpu: "Gpu", width: int, height: int, *, depth: bool, clear: bool = True,
                 color: Image | None = None, depth_image: Image | None = None):
        v = vk()
        self.gpu, self.width, self.height, self.clear = gpu, width, height, clear
        self.color = color or gpu.image(width, height, COLOR_FORMAT)
        self.depth = (depth_image or gpu.image(width, height, DEPTH_FORMAT)) if depth else None
        self._owned = [i for i, given in ((self.color, color), (self.depth, depth_image))
                       if i is not None and given is None]
        load = v.VK_ATTACHMENT_LOAD_OP_CLEAR if clear else v.VK_ATTACHMENT_LOAD_OP_LOAD
        general = v.VK_IMAGE_LAYOUT_GENERAL
        attachments = [v.VkAttachmentDescription(
            format=self.color.format, samples=v.VK_SAMPLE_COUNT_1_BIT, loadOp=load,
            storeOp=v.VK_ATTACHMENT_STORE_OP_STORE, stencilLoadOp=v.VK_ATTACHMENT_LOAD_OP_DONT_CARE,
            stencilStoreOp=v.VK_ATTACHMENT_STORE_OP_DONT_CARE, initialLayout=general,
            finalLayout=general)]
        color_ref = v.VkAttachmentReference(attachment=0, layout=general)
        color_refs = [color_ref]
        depth_ref = None
        if self.depth is not None:
            attachments.append(v.VkAttachmentDescription(
                format=self.depth.format, samples=v.VK_SAMPLE_COUNT_1_BIT, loadOp=load,
                storeOp=v.VK_ATTACHMENT_STORE_OP_STORE,
                stencilLoadOp=v.VK_ATTACHMENT_LOAD_OP_DONT_CARE,
                stencilStoreOp=v.VK_ATTACHMENT_STORE_OP_DONT_CARE, initialLayout=general,
                finalLayout=general))
            depth_ref = v.VkAttachmentReference(attachment=1, layout=general)
        subpass = v.VkSubpassDescription(
            pipelineBindPoint=v.VK_PIPELINE_BIND_POINT_GRAPHICS, colorAttachmentCount=1,
            pColorAttachments=color_refs, pDepthStencilAttachment=depth_ref)
        subpasses = [subpass]
        info = v.VkRenderPassCreateInfo(attachmentCount=len(attachments), pAttachments=attachments,
                                        subpassCount=1, pSubpasses=subpasses)
        self.render_pass = call("vkCreateRenderPass", v.vkCreateRenderPass, gpu.device, info, None)
        views = [self.color.view] + ([self.depth.view] if self.depth is not None else [])
        fb_info = v.VkFramebufferCreateInfo(renderPass=self.render_pass, attachmentCount=len(views),
                                            pAttachments=views, width=width, height=height,
                                            layers=1)
        self.framebuffer = call("vkCreateFramebuffer", v.vkCreateFramebuffer, gpu.device,
                                fb_info, None)

    def begin(self, cmd: Any, rgba: Sequence[float] = (0.0, 0.0, 0.0, 0.0)) -> None:
        """Begin the render pass (clearing colour to `rgba`, depth to 1) and set viewport/scissor."""
        v = vk()
        color = v.VkClearValue(color=v.VkClearColorValue(float32=list(rgba)))
        clears = [color]
        if self.depth is not None:
            clears.append(v.VkClearValue(depthStencil=v.VkClearDepthStencilValue(depth=1.0,
                                                                                 stencil=0)))
        area = v.VkRect2D(offset=v.VkOffset2D(x=0, y=0),
                          extent=v.VkExtent2D(width=self.width, height=self.height))
        begin = v.VkRenderPassBeginInfo(renderPass=self.render_pass, framebuffer=self.framebuffer,
                                        renderArea=area, clearValueCount=len(clears),
                                        pClearValues=clears)
        v.vkCmdBeginRenderPass(cmd, begin, v.VK_SUBPASS_CONTENTS_INLINE)
        viewport = v.VkViewport(x=0, y=0, width=self.width, height=self.height, minDepth=0.0,
                                maxDepth=1.0)
        viewports = [viewport]
        scissors = [area]
        v.vkCmdSetViewport(cmd, 0, 1, viewports)
        v.vkCmdSetScissor(cmd, 0, 1, scissors)

    def destroy(self) -> None:
        v = vk()
        v.vkDestroyFramebuffer(self.gpu.device, self.framebuffer, None)
        v.vkDestroyRenderPass(self.gpu.device, self.render_pass, None)
        for image in self._owned:
            image.destroy()


class Pipeline:
    """A graphics or compute pipeline with its layout, descriptor-set layout and pool."""

    def __init__(self, gpu: "Gpu", *, bind_point: int, set_layout: Any, layout: Any,
                 handle: Any, descriptor_type: int | None, max_sets: int):
        v = vk()
        self.gpu, self.bind_point, self.set_layout = gpu, bind_point, set_layout
        self.layout, self.handle, self.descriptor_type = layout, handle, descriptor_type
        self.pool = None
        if descriptor_type is not None:
            size = v.VkDescriptorPoolSize(type=descriptor_type, descriptorCount=max_sets * 4)
            sizes = [size]
            info = v.VkDescriptorPoolCreateInfo(maxSets=max_sets, poolSizeCount=1,
                                                pPoolSizes=sizes)
            self.pool = call("vkCreateDescriptorPool", v.vkCreateDescriptorPool, gpu.device,
                             info, None)
        self.sampler = None

    def descriptor_set(self, resources: Sequence[Image | Buffer]) -> Any:
        """Allocate a set binding `resources` in order (images sampled, buffers storage)."""
        v = vk()
        layouts = [self.set_layout]
        alloc = v.VkDescriptorSetAllocateInfo(descriptorPool=self.pool, descriptorSetCount=1,
                                              pSetLayouts=layouts)
        dset = call("vkAllocateDescriptorSets", v.vkAllocateDescriptorSets, self.gpu.device,
                    alloc)[0]
        keep: list[Any] = []
        writes = []
        for i, res in enumerate(resources):
            if isinstance(res, Image):
                info = v.VkDescriptorImageInfo(sampler=self._get_sampler(), imageView=res.view,
                                               imageLayout=v.VK_IMAGE_LAYOUT_GENERAL)
                infos = [info]
                keep.append(infos)
                writes.append(v.VkWriteDescriptorSet(
                    dstSet=dset, dstBinding=i, descriptorCount=1,
                    descriptorType=v.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, pImageInfo=infos))
            else:
                binfo = v.VkDescriptorBufferInfo(buffer=res.handle, offset=0, range=v.UINT64_MAX)
                binfos = [binfo]
                keep.append(binfos)
                writes.append(v.VkWriteDescriptorSet(
                    dstSet=dset, dstBinding=i, descriptorCount=1,
                    descriptorType=v.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, pBufferInfo=binfos))
        v.vkUpdateDescriptorSets(self.gpu.device, len(writes), writes, 0, None)
        return dset

    def _get_sampler(self) -> Any:
        if self.sampler is None:
            v = vk()
            edge = v.VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE
            info = v.VkSamplerCreateInfo(magFilter=v.VK_FILTER_NEAREST, minFilter=v.VK_FILTER_NEAREST,
                                         mipmapMode=v.VK_SAMPLER_MIPMAP_MODE_NEAREST,
                                         addressModeU=edge, addressModeV=edge, addressModeW=edge,
                                         maxLod=0.0)
            self.sampler = call("vkCreateSampler", v.vkCreateSampler, self.gpu.device, info, None)
        return self.sampler

    def bind(self, cmd: Any, dset: Any = None) -> None:
        v = vk()
        v.vkCmdBindPipeline(cmd, self.bind_point, self.handle)
        if dset is not None:
            sets = [dset]
            v.vkCmdBindDescriptorSets(cmd, self.bind_point, self.layout, 0, 1, sets, 0, None)

    def push(self, cmd: Any, stages: int, data: bytes) -> None:
        v = vk()
        buf = v.ffi.new("char[]", data)
        v.vkCmdPushConstants(cmd, self.layout, stages, 0, len(data), buf)

    def destroy(self) -> None:
        v = vk()
        dev = self.gpu.device
        v.vkDestroyPipeline(dev, self.handle, None)
        v.vkDestroyPipelineLayout(dev, self.layout, None)
        v.vkDestroyDescriptorSetLayout(dev, self.set_layout, None)
        if self.pool is not None:
            v.vkDestroyDescriptorPool(dev, self.pool, None)
        if self.sampler is not None:
            v.vkDestroySampler(dev, self.sampler, None)


def _layouts(gpu: "Gpu", dtype: int | None, count: int, stage: int, push_size: int,
             push_stages: int) -> tuple[Any, Any]:
    v = vk()
    bindings = [v.VkDescriptorSetLayoutBinding(binding=i, descriptorType=dtype, descriptorCount=1,
                                               stageFlags=stage) for i in range(count)]
    info = v.VkDescriptorSetLayoutCreateInfo(bindingCount=len(bindings),
                                             pBindings=bindings or None)
    set_layout = call("vkCreateDescriptorSetLayout", v.vkCreateDescriptorSetLayout, gpu.device,
                      info, None)
    rng = v.VkPushConstantRange(stageFlags=push_stages, offset=0, size=push_size)
    ranges = [rng]
    set_layouts = [set_layout]
    linfo = v.VkPipelineLayoutCreateInfo(setLayoutCount=1, pSetLayouts=set_layouts,
                                         pushConstantRangeCount=1, pPushConstantRanges=ranges)
    try:
        layout = call("vkCreatePipelineLayout", v.vkCreatePipelineLayout, gpu.device, linfo, None)
    except BaseException:
        v.vkDestroyDescriptorSetLayout(gpu.device, set_layout, None)
        raise
    return set_layout, layout


@contextmanager
def _building(gpu: "Gpu", set_layout: Any, layout: Any) -> Iterator[list[Any]]:
    """Yields a list for the shader modules a pipeline is built from: they are destroyed once
    the pipeline exists (or failed to); on failure the layouts are destroyed too."""
    v = vk()
    modules: list[Any] = []
    try:
        yield modules
    except BaseException:
        v.vkDestroyPipelineLayout(gpu.device, layout, None)
        v.vkDestroyDescriptorSetLayout(gpu.device, set_layout, None)
        raise
    finally:
        for module in modules:
            v.vkDestroyShaderModule(gpu.device, module, None)


def _vertex_input(attributes: Sequence[tuple[int, str, int]], stride: int,
                  strides: Sequence[int]) -> tuple[list[Any], list[Any]]:
    """The vertex bindings and attributes: all in binding 0 of `stride`, or attribute k in
    binding k of `strides[k]`."""
    v = vk()
    if not attributes:
        return [], []
    if strides and len(strides) != len(attributes):
        raise ValueError(f"{len(strides)} vertex buffer strides for {len(attributes)} attributes")
    sizes = list(strides) or [stride]
    bindings = [v.VkVertexInputBindingDescription(binding=k, stride=size,
                                                  inputRate=v.VK_VERTEX_INPUT_RATE_VERTEX)
                for k, size in enumerate(sizes)]
    attrs = [v.VkVertexInputAttributeDescription(location=loc, binding=k if strides else 0,
                                                 format=getattr(v, f"VK_FORMAT_{fmt}"), offset=off)
             for k, (loc, fmt, off) in enumerate(attributes)]
    return bindings, attrs


def graphics_pipeline(gpu: "Gpu", target: RenderTarget, vert: str, frag: str, *,
                      samplers: int = 0, push_size: int = 48,
                      vertex_attributes: Sequence[tuple[int, str, int]] = (), stride: int = 0,
                      strides: Sequence[int] = (), depth_test: bool = False,
                      blend_add: bool = False, cull_back: bool = False,
                      max_sets: int = 64) -> Pipeline:
    """A pipeline for `target`'s render pass; attributes are (location, VK_FORMAT suffix,
    offset) in one vertex buffer of `stride` bytes, or with `strides` one buffer per attribute
    (attribute k in binding k). `cull_back`: back faces culled, counter-clockwise in front."""
    v = vk()
    stage_v, stage_f = v.VK_SHADER_STAGE_VERTEX_BIT, v.VK_SHADER_STAGE_FRAGMENT_BIT
    dtype = v.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER
    set_layout, layout = _layouts(gpu, dtype, samplers, stage_f, push_size, stage_v | stage_f)
    with _building(gpu, set_layout, layout) as modules:
        modules.append(shader_module(gpu, vert))
        modules.append(shader_module(gpu, frag))
        vmod, fmod = modules
        entry = "main"
        stages = [v.VkPipelineShaderStageCreateInfo(stage=stage_v, module=vmod, pName=entry),
                  v.VkPipelineShaderStageCreateInfo(stage=stage_f, module=fmod, pName=entry)]
        vbindings, attrs = _vertex_input(vertex_attributes, stride, strides)
        vinput = v.VkPipelineVertexInputStateCreateInfo(
            vertexBindingDescriptionCount=len(vbindings), pVertexBindingDescriptions=vbindings or None,
            vertexAttributeDescriptionCount=len(attrs), pVertexAttributeDescriptions=attrs or None)
        assembly = v.VkPipelineInputAssemblyStateCreateInfo(
            topology=v.VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST, primitiveRestartEnable=v.VK_FALSE)
        viewport = v.VkPipelineViewportStateCreateInfo(viewportCount=1, scissorCount=1)
        raster = v.VkPipelineRasterizationStateCreateInfo(
            polygonMode=v.VK_POLYGON_MODE_FILL,
            cullMode=v.VK_CULL_MODE_BACK_BIT if cull_back else v.VK_CULL_MODE_NONE,
            frontFace=v.VK_FRONT_FACE_COUNTER_CLOCKWISE, lineWidth=1.0)
        multisample = v.VkPipelineMultisampleStateCreateInfo(
            rasterizationSamples=v.VK_SAMPLE_COUNT_1_BIT)
        depth = v.VkPipelineDepthStencilStateCreateInfo(
            depthTestEnable=v.VK_TRUE if depth_test else v.VK_FALSE,
            depthWriteEnable=v.VK_TRUE if depth_test else v.VK_FALSE,
            depthCompareOp=v.VK_COMPARE_OP_LESS, maxDepthBounds=1.0)
        one = v.VK_BLEND_FACTOR_ONE
        attachment = v.VkPipelineColorBlendAttachmentState(
            blendEnable=v.VK_TRUE if blend_add else v.VK_FALSE, srcColorBlendFactor=one,
            dstColorBlendFactor=one, colorBlendOp=v.VK_BLEND_OP_ADD, srcAlphaBlendFactor=one,
            dstAlphaBlendFactor=one, alphaBlendOp=v.VK_BLEND_OP_ADD, colorWriteMask=0xF)
        attachments = [attachment]
        blend = v.VkPipelineColorBlendStateCreateInfo(attachmentCount=1, pAttachments=attachments)
        dyn_states = [v.VK_DYNAMIC_STATE_VIEWPORT, v.VK_DYNAMIC_STATE_SCISSOR]
        dynamic = v.VkPipelineDynamicStateCreateInfo(dynamicStateCount=2, pDynamicStates=dyn_states)
        info = v.VkGraphicsPipelineCreateInfo(
            stageCount=2, pStages=stages, pVertexInputState=vinput, pInputAssemblyState=assembly,
            pViewportState=viewport, pRasterizationState=raster, pMultisampleState=multisample,
            pDepthStencilState=depth if target.depth is not None else None,
            pColorBlendState=blend, pDynamicState=dynamic, layout=layout,
            renderPass=target.render_pass, subpass=0)
        infos = [info]
        handle = call("vkCreateGraphicsPipelines", v.vkCreateGraphicsPipelines, gpu.device, None,
                      1, infos, None)[0]
    return Pipeline(gpu, bind_point=v.VK_PIPELINE_BIND_POINT_GRAPHICS, set_layout=set_layout,
                    layout=layout, handle=handle, descriptor_type=dtype if samplers else None,
                    max_sets=max_sets)


def compute_pipeline(gpu: "Gpu", comp: str, *, buffers: int, push_size: int,
                     max_sets: int = 8) -> Pipeline:
    """A compute pipeline whose set 0 holds `buffers` storage buffers."""
    v = vk()
    stage = v.VK_SHADER_STAGE_COMPUTE_BIT
    dtype = v.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER
    set_layout, layout = _layouts(gpu, dtype, buffers, stage, push_size, stage)
    with _building(gpu, set_layout, layout) as modules:
        modules.append(shader_module(gpu, comp))
        module = modules[0]
        entry = "main"
        stage_info = v.VkPipelineShaderStageCreateInfo(stage=stage, module=module, pName=entry)
        info = v.VkComputePipelineCreateInfo(stage=stage_info, layout=layout)
        infos = [info]
        handle = call("vkCreateComputePipelines", v.vkCreateComputePipelines, gpu.device, None,
                      1, infos, None)[0]
    return Pipeline(gpu, bind_point=v.VK_PIPELINE_BIND_POINT_COMPUTE, set_layout=set_layout,
                    layout=layout, handle=handle, descriptor_type=dtype, max_sets=max_sets)
